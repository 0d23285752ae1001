"""Residuals against the noise model: chi-square, whiteness (Ljung-Box), normality, correlation between sensors, and structure against each covariate."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from metrology.core.effects import Covariates


#: decision thresholds (family-wise levels, Bonferroni-split over the candidates / tests),
#: set a priori and checked on null data (benchmarks/study_diagnose.py, docs/readme_diagnose.md)
THRESHOLDS = {
    "alpha_candidates": 0.01,  # family-wise level of the in-sample F-tests over all candidates
    "alpha_heldout": 0.05,  # level of the one-sided held-out gain test (confirms the F-test)
    "alpha_battery": 0.01,  # family-wise level of the noise-model tests on the residuals
    "alpha_outlier": 0.01,  # family-wise level of the largest standardised residual
    "alpha_confound": 0.05,  # runner-up's gain not distinguishable from the winner's at this level
    "corr_confound": 0.95,  # |correlation| of a component parameter with a base parameter
    "alpha_form": 0.01,  # level of the datum cloud's form against the readings' (disagreement)
}


@dataclass(frozen=True)
class NoiseTests:
    """The noise-model battery of :func:`noise_tests`.

    Attributes
    ----------
    summary : dict
        The public result (``sensors``, ``pairs``, ``n_tests``, ``p_bonferroni``,
        ``consistent``; ``p_concerned`` added after an extension); read as ``tests[key]``.
    pvalues : tuple of (float, set of int)
        Every test's p-value with the sensors it involves (for :func:`battery_on`).
    """

    summary: dict
    pvalues: tuple

    def __getitem__(self, key):
        return self.summary[key]

    def to_dict(self) -> dict:
        return dict(self.summary)


def ljung_box(x, lags):
    """Ljung-Box portmanteau p-value of the series ``x`` (1-D, in order) up to ``lags``."""
    from scipy.stats import chi2

    x = np.asarray(x, float)
    x = x - x.mean()
    m = len(x)
    c0 = x @ x
    if c0 <= 0 or m <= lags + 1:
        return 1.0
    rho = np.array([x[k:] @ x[:-k] / c0 for k in range(1, lags + 1)])
    q = m * (m + 2) * np.sum(rho**2 / (m - np.arange(1, lags + 1)))
    return float(chi2.sf(q, lags))


def noise_tests(residual, sigma, dof_per_sensor, names, pairs=True):
    """Tests of the residuals ``(p, n)`` mm against white Gaussian noise of ``sigma (n,)`` mm.

    Returns a dict with per-sensor chi-square (upper tail), Ljung-Box and Shapiro-Wilk
    p-values, pairwise within-pose correlations with p-values, the Bonferroni-combined
    p-value and ``consistent`` at ``alpha_battery``.
    """
    from scipy import stats

    n = residual.shape[1]
    per = {}
    pvals = []
    for i in range(n):
        r = residual[:, i]
        r = r[np.isfinite(r)]
        chi2 = float(np.sum((r / sigma[i]) ** 2))
        dof = max(int(dof_per_sensor[i]), 1)
        p_chi = float(stats.chi2.sf(chi2, dof))
        p_lb = ljung_box(r, min(10, max(len(r) // 5, 1)))
        p_sw = float(stats.shapiro(r).pvalue) if len(r) >= 3 else 1.0
        per[names[i]] = {"chi2": chi2, "dof": dof, "sigma_est_mm": float(np.sqrt(chi2 / dof)) * sigma[i],
                         "p_chi2": p_chi, "p_whiteness": p_lb, "p_normality": p_sw}
        pvals += [(p_chi, {i}), (p_lb, {i}), (p_sw, {i})]
    pair_out = {}
    for i in range(n if pairs else 0):
        for j in range(i + 1, n):
            ok = np.isfinite(residual[:, i]) & np.isfinite(residual[:, j])
            if ok.sum() < 4:
                continue
            rr, pp = stats.pearsonr(residual[ok, i], residual[ok, j])
            pair_out[f"{names[i]}-{names[j]}"] = {"r": float(rr), "p": float(pp)}
            pvals.append((float(pp), {i, j}))
    p_all = min(1.0, min(p for p, _ in pvals) * len(pvals))
    return NoiseTests({"sensors": per, "pairs": pair_out, "n_tests": len(pvals), "p_bonferroni": p_all,
                       "consistent": bool(p_all >= THRESHOLDS["alpha_battery"])}, tuple(pvals))


def battery_on(tests, sensors):
    """Bonferroni p-value of the tests of :func:`noise_tests` that involve ``sensors`` (indices).

    The family is the whole battery (its ``n_tests``), not the subset: the check after an
    extension is then no stricter than the verdict on the base residuals, and the same
    residuals cannot pass the base battery yet fail the subset's (a chance correlation of
    two sensors at p = 0.001 does that with a 6-test subset).
    """
    ps = [p for p, inv in tests.pvalues if inv & set(sensors)]
    return min(1.0, min(ps) * tests["n_tests"]) if ps else 1.0


def structure(residual, d0, cov: Covariates, names):
    """Residuals against each covariate: per sensor, the quadratic-fit R^2 and F-test p-value.

    Returns dict covariate -> sensor -> {"r2", "p"}.
    """
    from scipy import stats

    p, n = residual.shape
    variables = {
        "d_mm": d0,
        "incidence_deg": np.rad2deg(np.arccos(np.clip(cov.cos_inc, -1, 1))),
        "time_h": np.broadcast_to(cov.time_h[:, None], (p, n)),
        "temp_c": np.broadcast_to(cov.temp_c[:, None], (p, n)),
        "spot_s_mm": cov.spot_st[..., 0],
        "spot_t_mm": cov.spot_st[..., 1],
        "pose_index": np.broadcast_to(np.arange(p, dtype=float)[:, None], (p, n)),
    }
    out = {}
    for key, X in variables.items():
        if not np.all(np.isfinite(X)):
            continue
        row = {}
        for i in range(n):
            ok = np.isfinite(residual[:, i])
            y, x = residual[ok, i], X[ok, i]
            if np.ptp(x) == 0 or len(y) < 6:
                continue
            xs = (x - x.mean()) / np.ptp(x)
            A = np.stack([np.ones_like(xs), xs, xs**2], axis=1)
            coef, *_ = np.linalg.lstsq(A, y, rcond=None)
            ss_res = float(np.sum((y - A @ coef) ** 2))
            ss_tot = float(np.sum((y - y.mean()) ** 2))
            r2 = 1 - ss_res / ss_tot if ss_tot > 0 else 0.0
            F = (ss_tot - ss_res) / 2 / max(ss_res / (len(y) - 3), 1e-300)
            row[names[i]] = {"r2": r2, "p": float(stats.f.sf(F, 2, len(y) - 3))}
        out[key] = row
    return out


def _chi2_other(base, sigma, S):
    other = [i for i in range(base.residual.shape[1]) if i not in S]
    r = base.residual[:, other] / sigma[other]
    return float(np.nansum(r**2))

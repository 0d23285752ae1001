"""Statistics of the residuals: the noise-model battery and the structure table."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects import Covariates
from metrology.diagnosis import rules

__all__ = ["NoiseTests", "SensorTests", "PairTest", "Trend", "Battery", "ljung_box", "noise_tests", "battery_on", "battery_rng", "paired_gain_p", "structure"]


@dataclass(frozen=True)
class SensorTests:
    """The noise-model tests of one sensor's residuals (:func:`noise_tests`).

    chi2 : float, the sum of the squared residuals over the stated noise (unitless); dof : int;
    sigma_est_mm : float, mm, the noise the residuals show (``sigma sqrt(chi2 / dof)``);
    p_chi2 : float, chi-square upper tail; p_whiteness : float, Ljung-Box (:func:`ljung_box`);
    p_normality : float or None, Shapiro-Wilk (None: not run)."""

    chi2: float
    dof: int
    sigma_est_mm: float
    p_chi2: float
    p_whiteness: float
    p_normality: float | None

    def to_dict(self) -> dict:
        return {"chi2": self.chi2, "dof": self.dof, "sigma_est_mm": self.sigma_est_mm, "p_chi2": self.p_chi2,
                "p_whiteness": self.p_whiteness, "p_normality": self.p_normality}


@dataclass(frozen=True)
class PairTest:
    """Two sensors' residuals within a pose: r : float, Pearson's correlation (unitless); p : float, its p-value."""

    r: float
    p: float

    def to_dict(self) -> dict:
        return {"r": self.r, "p": self.p}


@dataclass(frozen=True)
class NoiseTests:
    """The noise-model battery on one set of residuals (:func:`noise_tests`).

    Attributes
    ----------
    sensors : dict, sensor name -> :class:`SensorTests`
    pairs : dict, ``"A-B"`` (two sensors' names) -> :class:`PairTest`, their within-pose correlation
    n_tests : int, the size of the family
    p_bonferroni : float, Bonferroni-combined p-value
    consistent : bool, at ``alpha_battery``
    pvalues : tuple of (p, set of sensor indices), every test with the sensors it involves
    p_concerned : float or None, :func:`battery_on` the sensors of an extension (after one)
    """

    sensors: dict[str, SensorTests]
    pairs: dict[str, PairTest]
    n_tests: int
    p_bonferroni: float
    consistent: bool
    pvalues: tuple = ()
    p_concerned: float | None = None

    def to_dict(self) -> dict:
        out = {"sensors": {k: t.to_dict() for k, t in self.sensors.items()},
               "pairs": {k: t.to_dict() for k, t in self.pairs.items()}, "n_tests": self.n_tests,
               "p_bonferroni": self.p_bonferroni, "consistent": self.consistent}
        if self.p_concerned is not None:
            out["p_concerned"] = self.p_concerned
        return out


def _lb_q(x, lags):
    """Ljung-Box Q of each row of ``x (B, m)`` (rows already centred), up to ``lags``."""
    m = x.shape[1]
    c0 = np.einsum("bi,bi->b", x, x)
    q = np.zeros(x.shape[0])
    for k in range(1, lags + 1):
        rho = np.einsum("bi,bi->b", x[:, k:], x[:, :-k]) / c0
        q += rho**2 / (m - k)
    return m * (m + 2) * q


def ljung_box(x, lags, rng: np.random.Generator | None = None, n_perm: int = 9999):
    """Ljung-Box portmanteau p-value of the series ``x`` (1-D, in order) up to ``lags``.

    With ``rng`` the p-value is a permutation test: ``Q`` against ``n_perm`` random orders of
    the same values, exact for exchangeable residuals whatever their number (the smallest is
    ``1/(n_perm + 1)``). Without it, the chi-square approximation, which is not calibrated in the
    tail for the 40-150 poses of a calibration: on white Gaussian noise of 56 values it gives
    p < 1e-4 twenty times too often (2 in 1000 series), and the battery then calls 2-4 % of
    null data sets inconsistent instead of 1 % (measured: benchmarks/study_blind.py nulls).
    """
    from scipy.stats import chi2

    x = np.asarray(x, float)
    x = x - x.mean()
    m = len(x)
    if x @ x <= 0 or m <= lags + 1:
        return 1.0
    q = float(_lb_q(x[None], lags)[0])
    if rng is None:
        return float(chi2.sf(q, lags))
    count, done = 0, 0
    while done < n_perm:  # in blocks: memory stays ~ 2000 x m
        b = min(2000, n_perm - done)
        qp = _lb_q(rng.permuted(np.broadcast_to(x, (b, m)), axis=1), lags)
        count += int(np.sum(qp >= q * (1 - 1e-12)))
        done += b
    return (1 + count) / (n_perm + 1)


@dataclass(frozen=True)
class Battery:
    """Which tests of :func:`noise_tests` run beside the chi-square and whiteness: ``pairs`` the
    within-pose correlations of the sensors, ``normality`` Shapiro-Wilk."""

    pairs: bool = True
    normality: bool = True


def noise_tests(residual, sigma, dof_per_sensor, names, rng: np.random.Generator | None = None,
                battery: Battery = Battery()) -> NoiseTests:
    """Tests of the residuals ``(p, n)`` mm against white Gaussian noise of ``sigma (n,)`` mm
    (``battery``: which tests run beside the chi-square and whiteness).

    Returns a :class:`NoiseTests`: per-sensor chi-square (upper tail), Ljung-Box (a permutation
    test when ``rng`` is given, see :func:`ljung_box`) and Shapiro-Wilk p-values, pairwise within-pose correlations with p-values, the Bonferroni-combined
    p-value and ``consistent`` at ``alpha_battery``.
    """
    from scipy import stats

    pairs, normality = battery.pairs, battery.normality
    n = residual.shape[1]
    per = {}
    pvals = []
    for i in range(n):
        r = residual[:, i]
        r = r[np.isfinite(r)]
        chi2 = float(np.sum((r / sigma[i]) ** 2))
        dof = max(int(dof_per_sensor[i]), 1)
        p_chi = float(stats.chi2.sf(chi2, dof))
        p_lb = ljung_box(r, min(10, max(len(r) // 5, 1)), rng)
        p_sw = float(stats.shapiro(r).pvalue) if len(r) >= 3 and normality else None
        per[names[i]] = SensorTests(chi2, dof, float(np.sqrt(chi2 / dof)) * sigma[i], p_chi, p_lb, p_sw)
        pvals += [(p_chi, {i}), (p_lb, {i})] + ([(p_sw, {i})] if p_sw is not None else [])
    pair_out = {}
    for i in range(n if pairs else 0):
        for j in range(i + 1, n):
            ok = np.isfinite(residual[:, i]) & np.isfinite(residual[:, j])
            if ok.sum() < 4:
                continue
            rr, pp = stats.pearsonr(residual[ok, i], residual[ok, j])
            pair_out[f"{names[i]}-{names[j]}"] = PairTest(float(rr), float(pp))
            pvals.append((float(pp), {i, j}))
    p_all = min(1.0, min(p for p, _ in pvals) * len(pvals))
    return NoiseTests(per, pair_out, len(pvals), p_all, rules.explains_sensors(p_all), tuple(pvals))


def battery_rng() -> np.random.Generator:
    """The generator of the battery's permutation tests: fixed, so the verdict is a function of
    the data alone (``diagnose``'s ``seed`` drives only the side-by-side simulation)."""
    return np.random.default_rng(20261123)


def paired_gain_p(d) -> float:
    """One-sided paired t-test that the per-pose differences ``d (p,)`` (a chi-square without a
    cause less the chi-square with it) are positive: the cause predicts held-out poses better.
    1 where every difference is zero (the two models predict alike; the t statistic is undefined)."""
    from scipy import stats

    d = np.asarray(d, float)
    return 1.0 if np.allclose(d, 0) else float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue)


def battery_on(tests: NoiseTests, sensors) -> float:
    """Bonferroni p-value of the tests of :func:`noise_tests` that involve ``sensors`` (indices).

    The family is the whole battery (its ``n_tests``), not the subset: the check after an
    extension is then no stricter than the verdict on the base residuals, and the same
    residuals cannot pass the base battery yet fail the subset's (a chance correlation of
    two sensors at p = 0.001 does that with a 6-test subset).
    """
    ps = [p for p, inv in tests.pvalues if inv & set(sensors)]
    return min(1.0, min(ps) * tests.n_tests) if ps else 1.0


@dataclass(frozen=True)
class Trend:
    """One cell of the structure table (:func:`structure`): a sensor's base residuals against one
    covariate, fitted with a quadratic.

    r2 : float, the quadratic fit's R^2 (unitless, 0-1); p : float, its F-test's p-value (2 and
    m - 3 dof, m the sensor's finite readings)."""

    r2: float
    p: float

    def to_dict(self) -> dict:
        return {"r2": self.r2, "p": self.p}


def structure(residual, d0, cov: Covariates, names) -> dict[str, dict[str, Trend]]:
    """Residuals against each covariate: per sensor, the quadratic-fit R^2 and F-test p-value.

    Returns dict covariate (``d_mm``, ``incidence_deg``, ...) -> sensor name -> :class:`Trend`
    (a covariate not finite everywhere, a sensor with a constant covariate or fewer than 6
    readings, left out).
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
            row[names[i]] = Trend(r2, float(stats.f.sf(F, 2, len(y) - 3)))
        out[key] = row
    return out


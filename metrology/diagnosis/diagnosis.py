"""Diagnosis: what the simple model misses, which catalogued effect it is, and the gain.

The procedure (issue 6):

1. **Discrepancy.** Calibrate the base model (5 chart parameters per sensor, batch least
   squares weighted by the stated ``noise_mm``). Side by side: what the simulation predicts
   for this data set (the same poses and layout, the stated noise, analysed the same way)
   and what the measurements give: in-sample residual RMS per sensor and the k-fold held-out
   normal deviation. The residuals are tested against the noise model (chi-square per sensor
   against ``noise_mm``, Ljung-Box whiteness in pose order, Shapiro-Wilk normality, and the
   correlation of sensors within a pose), and their structure is tabulated against the
   reading, the incidence angle, time, temperature, the spot on the datum and pose index.
2. **Candidates.** Every catalogued component (per sensor where it belongs to one sensor)
   is added to the base model and scored: an in-sample F-test of the nested models and the
   k-fold-by-pose held-out gain (a one-sided paired t-test on the per-pose held-out
   chi-square of the candidate's sensors, base against extended). A candidate is *significant* when both
   p-values are below the thresholds of :data:`THRESHOLDS`; the named cause is the
   significant candidate with the largest held-out chi-square reduction. ``none``: no
   significant candidate and residuals consistent with the noise model; ``unexplained``:
   residuals inconsistent with the noise model and either no significant candidate or the
   best one leaves them inconsistent (it is reported as a partial explanation).
   Confounding: a runner-up whose held-out gain cannot be told from the winner's, and the
   correlation of the component's parameters with the base parameters, are reported with
   the poses that would separate them.
3. **Extension.** The named component is re-identified with the base parameters; each extra
   parameter comes with its standard error (``s^2 (J^T J)^-1``). The extended model drives
   the simulator, and the side-by-side table is repeated with it.
4. **Gain.** k-fold by pose: held-out residual RMS (a per-pose value predicted from the
   other sensors of its pose) and normal angular deviation, base against extended, and their ratio.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from metrology.core.effects import (VERDICTS, Covariates, Drift, ExtendedModel, Incidence, Nonlinearity,
                      Outliers, PlaneForm, PoseError, Scale)
from metrology.calibration.estimators import Observations
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, direction_from_tangent, jacobian_raw, jacobian_tangent, readings

__all__ = ["THRESHOLDS", "Fit", "fit", "Diagnosis", "diagnose", "diagnose_files", "candidates_for", "datum_form",
           "covariates_for", "ADVICE"]

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

#: the poses that separate each cause from the others
ADVICE = {
    "scale": "readings over the whole measuring range (a wider spread of stand-off)",
    "nonlinearity": "readings over the whole measuring range (a wider spread of stand-off)",
    "incidence": "a wider spread of tilt against the datum (incidence angles)",
    "drift": "poses repeated cold and warm, interleaved rather than in one sweep",
    "plane_form": "spots over the whole datum, each region seen at several tilts",
    "pose_error": "repeated poses, or more sensors per pose",
    "outliers": "the flagged poses repeated",
}


# ---------------------------------------------------------------------------------------
# the extended fit


@dataclass(frozen=True)
class Fit:
    """A fitted extended model.

    Attributes
    ----------
    theta : (n, 5) float, chart errors (mm, rad) around the nominal layout
    theta_stderr : (n, 5) float
    components : tuple of Component with values and stderr
    residual : (p, n) float, mm, measured minus predicted; NaN where no reading
    chi2 : float, sum of squared residuals over noise_mm (the fitted sensors)
    dof : int, readings minus free parameters (fitted sensors)
    sensors : tuple of int, the sensors whose parameters were free
    corr_base : (k,) float, per extra parameter the largest |correlation| with a base parameter
    corr_with : tuple of str, the base parameter of that correlation
    extra_cov : (k, k) float, covariance of the parameters of the components that are not per
        pose, in their order (``s^2 (J^T J)^-1``)
    """

    theta: np.ndarray
    theta_stderr: np.ndarray
    components: tuple
    residual: np.ndarray
    chi2: float
    dof: int
    sensors: tuple
    corr_base: np.ndarray = field(default_factory=lambda: np.zeros(0))
    corr_with: tuple = ()
    extra_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    def model(self, nominal: SensorLayout) -> ExtendedModel:
        zero = nominal.zero + self.theta[:, :3]
        u = direction_from_tangent(nominal.direction, self.theta[:, 3:])
        return ExtendedModel(nominal.with_params(zero, u), self.components)


def _geometry(nominal, theta):
    zero = nominal.zero + theta[:, :3]
    u = direction_from_tangent(nominal.direction, theta[:, 3:])
    return zero, u


def _project_per_pose(Bw, X, A):
    """Remove per-pose common modes: ``X - Bw e`` with ``e`` the weighted least-squares fit of
    each pose's rows of ``X`` on ``Bw`` under the gauge ``A^T e = 0``.

    Bw : (p, s) float, the per-pose column (zero where no reading); X : (p, s) or (p, s, k);
    A : (p, g) float, the gauge modes (for pose errors: the plane normal in each TCS, since a
    translation of every zero point by ``v`` is the per-pose error ``e_p = -N_p . v``).
    Returns (projected X, e (p,) or (p, k)).
    """
    bb = np.maximum(np.sum(Bw * Bw, axis=1), 1e-300)  # (p,)
    squeeze = X.ndim == 2
    Xk = X[..., None] if squeeze else X
    br = np.einsum("ps,psk->pk", Bw, Xk)  # (p, k)
    AW = A / bb[:, None]  # W^-1 A
    lam = np.linalg.solve(A.T @ AW, AW.T @ br)  # (g, k)
    e = (br - A @ lam) / bb[:, None]
    out = Xk - Bw[..., None] * e[:, None, :]
    return (out[..., 0], e[:, 0]) if squeeze else (out, e)


def fit(nominal: SensorLayout, obs: Observations, cov: Covariates, sigma, components=(), sensors=None,
        theta0=None, loss="linear", solver="lsq") -> Fit:
    """Least squares of the base model plus ``components`` (analytic Jacobian).

    Parameters
    ----------
    nominal : SensorLayout, the chart's centre
    obs : Observations
    cov : Covariates, same poses as ``obs``
    sigma : (n,) float, mm, reading noise used as weights
    components : sequence of Component (values are the starting point)
    sensors : sequence of int or None, the sensors whose base parameters are free and whose
        readings are fitted (default: every sensor if a component is of the set-up, else the
        components' sensors, else all)
    theta0 : (n, 5) float or None, start (and the fixed values of the other sensors)
    loss : ``"linear"`` or ``"soft_l1"`` (robust, scale 1 sigma)
    solver : ``"lsq"`` (``scipy.optimize.least_squares``, trf) or ``"gn"`` (Gauss-Newton on
        the same residual and Jacobian with step halving: the same minimum, several times
        faster; used inside the k-fold loops)

    A per-pose component (:class:`~metrology.effects.PoseError`) is profiled out exactly:
    its basis does not depend on the parameters, so for any base parameters the optimal
    per-pose values are a fixed linear map of the residual (variable projection); its values
    are then recovered with standard errors ``s / ||b_p||`` (reading noise only).
    """
    from scipy.optimize import least_squares

    n = nominal.n
    comps = tuple(components)
    ExtendedModel(nominal, comps)  # name clashes raise
    if loss not in ("linear", "soft_l1"):
        raise ValueError(f"loss must be 'linear' or 'soft_l1', got {loss!r}")
    if sensors is None:
        if not comps or any(not c.sensors for c in comps):
            sensors = range(n)
        else:
            sensors = sorted({i for c in comps for i in c.sensors})
    S = np.array(sorted(sensors), int)
    theta0 = np.zeros((n, 5)) if theta0 is None else np.array(theta0, float)
    N, D = obs.normal, obs.offset
    ok = np.isfinite(obs.d)[:, S]
    dS = np.where(ok, obs.d[:, S], 0.0)
    sig = np.asarray(sigma, float)[S]
    prof = [c for c in comps if c.per_pose]
    free = [c for c in comps if not c.per_pose]
    if len(prof) > 1:
        raise ValueError("at most one per-pose component per fit")
    k_comp = [c.n_params for c in free]
    nb = 5 * len(S)
    x0 = np.concatenate([theta0[S].ravel()] + [c.values for c in free])
    zero_all, u_all = _geometry(nominal, theta0)
    d_full0 = readings(zero_all, u_all, N, D)[0]
    basis0 = direction_basis(nominal.direction[S])
    u0S = nominal.direction[S]
    Bw = None
    if prof:
        Bw = np.where(ok, prof[0].basis(d_full0, cov)[np.arange(len(D)), :, np.arange(len(D))][:, S] / sig, 0.0)

    def unpack(x):
        th = theta0.copy()
        th[S] = x[:nb].reshape(-1, 5)
        vals, j = [], nb
        for k in k_comp:
            vals.append(x[j:j + k])
            j += k
        return th, vals

    def predict(x):
        th, vals = unpack(x)
        w = u0S + np.einsum("nk,nkj->nj", th[S, 3:], basis0)
        d0s, _ = readings(nominal.zero[S] + th[S, :3], w, N, D)
        d0 = d_full0.copy()
        d0[:, S] = d0s
        f = np.zeros_like(d0)
        for c, v in zip(free, vals):
            f += c.evaluate(v, d0, cov)
        return th, vals, d0, f

    def residual_matrix(x):
        th, vals, d0, f = predict(x)
        R = np.where(ok, (dS - d0[:, S] - f[:, S]) / sig, 0.0)
        e = None
        if Bw is not None:
            R, e = _project_per_pose(Bw, R, N)
        return R, e, th, vals, d0

    def fun(x):
        R, _, th, vals, _ = residual_matrix(x)
        extra = [c.constraint(v)[0] for c, v in zip(free, vals)]
        return np.concatenate([R[ok]] + extra)

    def jac(x):
        th, vals, d0, f = predict(x)
        J0 = jacobian_tangent(nominal.zero[S] + th[S, :3], u0S, th[S, 3:], N, D)  # (p, s, 5)
        g = np.ones_like(d0)
        for c, v in zip(free, vals):
            if c.uses_d0:
                g += c.d_dd0(v, d0, cov)
        J0 = J0 * g[:, S, None]
        p, s = ok.shape
        Jb = np.zeros((p, s, nb))
        for a in range(s):
            Jb[:, a, 5 * a:5 * a + 5] = J0[:, a]
        blocks = [Jb] + [c.jacobian(v, d0, cov)[:, S] for c, v in zip(free, vals)]
        Jr = -np.concatenate(blocks, axis=-1) / sig[None, :, None]
        Jr = np.where(ok[..., None], Jr, 0.0)
        if Bw is not None:
            Jr, _ = _project_per_pose(Bw, Jr, N)
        rows = [Jr[ok]]
        off = nb
        for c, v, k in zip(free, vals, k_comp):
            Jc = c.constraint(v)[1]
            if len(Jc):
                Rr = np.zeros((len(Jc), rows[0].shape[1]))
                Rr[:, off:off + k] = Jc
                rows.append(Rr)
            off += k
        return np.concatenate(rows, axis=0)

    if solver == "lsq":
        kw = {} if loss == "linear" else {"loss": loss, "f_scale": 1.0}
        x = least_squares(fun, x0, jac=jac, method="trf", x_scale="jac", **kw).x
    elif solver == "gn":
        x = _gauss_newton(fun, jac, x0, loss)
    else:
        raise ValueError(f"solver must be 'lsq' or 'gn', got {solver!r}")
    R, e, th, vals, d0 = residual_matrix(x)
    J = jac(x)
    f = predict(x)[3]
    res = np.full(obs.d.shape, np.nan)
    res[:, S] = np.where(ok, R * sig, np.nan)
    others = np.setdiff1d(np.arange(n), S)
    res[:, others] = obs.d[:, others] - d_full0[:, others] - f[:, others]
    rS = R[ok]
    m = rS.size
    k = J.shape[1] - sum(len(c.constraint(v)[0]) for c, v in zip(free, vals)) + (len(e) - N.shape[1] if e is not None else 0)
    dof = m - k
    chi2 = float(np.sum(rS**2))
    s2 = chi2 / max(dof, 1)
    # covariance s^2 (J^T J)^-1, column-scaled normal equations (small: base + few extras)
    scale = np.maximum(np.linalg.norm(J, axis=0), 1e-300)
    Js = J / scale
    C = np.linalg.pinv(Js.T @ Js, rcond=1e-12, hermitian=True) / np.outer(scale, scale) * s2
    se = np.sqrt(np.maximum(np.diag(C), 0.0))
    theta_se = np.zeros((n, 5))
    theta_se[S] = se[:nb].reshape(-1, 5)
    out, j = [], nb
    corr_b, corr_w = [], []
    base_names = [f"{nominal.names[i]}.{q}" for i in S for q in ("x", "y", "z", "a", "b")]
    it_free = iter(zip(free, vals))
    for c in comps:
        if c.per_pose:
            bb = np.sqrt(np.maximum(np.sum(Bw * Bw, axis=1), 1e-300))
            out.append(c.with_values(e, np.sqrt(s2) / bb))
            continue
        c2, v = next(it_free)
        kk = c2.n_params
        out.append(c2.with_values(v, se[j:j + kk]))
        for q in range(kk):
            cc = C[j + q, :nb] / np.maximum(se[j + q] * se[:nb], 1e-300)
            a = int(np.argmax(np.abs(cc)))
            corr_b.append(float(np.abs(cc[a])))
            corr_w.append(base_names[a])
        j += kk
    return Fit(th, theta_se, tuple(out), res, chi2, int(dof), tuple(int(i) for i in S), np.array(corr_b),
               tuple(corr_w), C[nb:, nb:])


def _gauss_newton(fun, jac, x0, loss, max_iter=30, tol=1e-10):
    """Gauss-Newton with step halving (IRLS weights for ``soft_l1``) on column-scaled normal
    equations; stops when the cost changes by less than ``tol`` relative."""

    def cost_of(r):
        z = r * r
        return float(np.sum(z) if loss == "linear" else np.sum(2 * (np.sqrt(1 + z) - 1)))

    x = np.array(x0, float)
    r = fun(x)
    cost = cost_of(r)
    for _ in range(max_iter):
        J = jac(x)
        w = np.ones_like(r) if loss == "linear" else 1.0 / np.sqrt(np.sqrt(1 + r * r))
        Jw, rw = J * w[:, None], r * w
        scale = np.maximum(np.linalg.norm(Jw, axis=0), 1e-300)
        Js = Jw / scale
        step = -np.linalg.lstsq(Js, rw, rcond=1e-12)[0] / scale
        t = 1.0
        while True:
            xn = x + t * step
            rn = fun(xn)
            cn = cost_of(rn)
            if cn <= cost or t < 1e-4:
                break
            t *= 0.5
        done = abs(cost - cn) <= tol * max(cost, 1e-300)
        if cn <= cost:
            x, r, cost = xn, rn, cn
        if done or cn > cost:
            break
    return x


# ---------------------------------------------------------------------------------------
# covariates and candidates


def covariates_for(ds, layout_fit: SensorLayout, centre=None) -> Covariates:
    """Covariates of a :class:`~metrology.dataset.Dataset` at the calibrated geometry.

    ``centre`` (3,) mm tracker: the datum centre; default the centroid of the datum cloud if
    there is one, else the mean of the spots projected on the plane.
    """
    obs = ds.obs
    ex = ds.export
    R, t = ex.tcs2tracker_rot, ex.tcs2tracker_trans
    rng_mm = layout_fit.range_mm.copy()
    bad = ~np.all(np.isfinite(rng_mm), axis=1)
    if np.any(bad):  # no stated range: the readings' own span
        lo, hi = np.nanmin(ex.d, axis=0), np.nanmax(ex.d, axis=0)
        rng_mm[bad] = np.stack([lo, hi], axis=1)[bad]
    if centre is None:
        if ds.datum_points is not None:
            centre = np.mean(ds.datum_points, axis=0)
        else:
            d, _ = readings(layout_fit.zero, layout_fit.direction, obs.normal, obs.offset)
            spots = np.einsum("pij,pnj->pni", R, layout_fit.zero[None] + d[..., None] * layout_fit.direction[None]) + t[:, None]
            centre = np.nanmean(spots.reshape(-1, 3), axis=0)
    centre = np.asarray(centre, float)
    centre = centre - ds.plane.distance(centre) * ds.plane.normal
    has_t = np.all(np.isfinite(ex.time_s))
    has_T = np.all(np.isfinite(ex.temp_c))
    return Covariates.from_geometry(layout_fit.zero, layout_fit.direction, obs.normal, obs.offset, R, t,
                                    ds.plane.normal, centre, rng_mm, ex.time_s if has_t else None,
                                    ex.temp_c if has_T else None)


def candidates_for(layout: SensorLayout, cov: Covariates, flags=None):
    """Every catalogued candidate component for this data set (values zero).

    ``flags`` (p, n) bool: readings flagged as gross (the ``outliers`` candidate); none if
    None or empty.
    """
    names = layout.names
    out = []
    for i in range(layout.n):
        out.append(Scale((i,), names=names))
        out.append(Incidence((i,), names=names))
        out.append(Nonlinearity((i,), names=names))
        # the reference is fixed once per data set (every fold evaluates against it) at the
        # run's mean, where the rate is least correlated with the zero point
        if np.all(np.isfinite(cov.temp_c)) and np.ptp(cov.temp_c) > 0:
            out.append(Drift((i,), names=names, variable="temp", ref=float(np.mean(cov.temp_c))))
        out.append(Drift((i,), names=names, variable="time", ref=float(np.mean(cov.time_h))))
    out.append(PlaneForm((), names=names))
    out.append(PoseError((), names=names, n_poses=cov.n_poses))
    if flags is not None and np.any(flags):
        out.append(Outliers(tuple(sorted(set(np.argwhere(flags)[:, 1].tolist()))), names=names, flags=flags))
    return out


# ---------------------------------------------------------------------------------------
# statistics


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
    return {"sensors": per, "pairs": pair_out, "n_tests": len(pvals), "p_bonferroni": p_all, "_p": pvals,
            "consistent": bool(p_all >= THRESHOLDS["alpha_battery"])}


def battery_on(tests, sensors):
    """Bonferroni p-value of the tests of :func:`noise_tests` that involve ``sensors`` (indices).

    The family is the whole battery (its ``n_tests``), not the subset: the check after an
    extension is then no stricter than the verdict on the base residuals, and the same
    residuals cannot pass the base battery yet fail the subset's (a chance correlation of
    two sensors at p = 0.001 does that with a 6-test subset).
    """
    ps = [p for p, inv in tests["_p"] if inv & set(sensors)]
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


# ---------------------------------------------------------------------------------------
# k-fold held-out evaluation


def _folds(p, k):
    """Interleaved folds by pose (pose j in fold j mod k): each fold spans the whole run."""
    return [np.arange(j, p, k) for j in range(k)]


def _heldout_eval(nominal, obs, cov, sigma, f: Fit, test):
    """Residuals (h, n) mm and normals of a fit on the held-out poses ``test``.

    A per-pose component's value of a held-out pose is fitted, for each reading, to the other
    sensors of that pose (leave one sensor out), so every residual is a prediction. Returns
    (residual (h, n) mm, normal deviation (h,) rad).
    """
    from metrology.core.normals import angle_between, micro_plane_normal

    o, c = obs.select(test), cov.select(test)
    zero, u = _geometry(nominal, f.theta)
    d0, _ = readings(zero, u, o.normal, o.offset)
    terms = np.zeros_like(d0)
    per_pose = []
    for comp in f.components:
        if comp.per_pose:
            per_pose.append(replace(comp, n_poses=len(test), values=None, stderr=None))
        elif isinstance(comp, Outliers):
            continue  # flagged held-out readings are left out of the figures
        else:
            terms += comp.evaluate(comp.values, d0, c)
    res = o.d - d0 - terms
    for comp in per_pose:
        # a per-pose value is not known before the pose is measured: each reading is predicted
        # with the value fitted to the *other* sensors of its pose (leave one sensor out), so
        # the held-out residual is a true prediction and nothing is charged as lost dof
        B = comp.basis(d0, c)  # (h, n, h)
        diag = B[np.arange(len(test)), :, np.arange(len(test))]  # (h, n)
        w = np.where(np.isfinite(res), diag / sigma[None, :], 0.0)
        r = np.where(np.isfinite(res), res / sigma[None, :], 0.0)
        wr, ww = np.sum(w * r, axis=1, keepdims=True), np.sum(w * w, axis=1, keepdims=True)
        e_loso = (wr - w * r) / np.maximum(ww - w * w, 1e-300)  # (h, n): without reading i
        e_all = wr[:, 0] / np.maximum(ww[:, 0], 1e-300)  # (h,): for the normal, every reading
        res = res - diag * e_loso
        terms = terms + diag * e_all[:, None]
    dc = o.d - terms
    nrm = micro_plane_normal(zero, u, dc)
    dev = angle_between(nrm, o.normal)
    return res, dev


@dataclass(frozen=True)
class HeldOut:
    """k-fold held-out figures of one model.

    Attributes
    ----------
    residual : (p, n) float, mm, held-out residuals (predictions: see :func:`_heldout_eval`)
    normal_dev : (p,) float, rad, held-out normal deviation
    """

    residual: np.ndarray
    normal_dev: np.ndarray

    def chi2_pose(self, sigma, cols=None, exclude=None):
        """Per-pose held-out chi-square ``(p,)`` over the sensors ``cols`` (default all),
        leaving out the readings ``exclude`` ((p, n) bool) if given."""
        r = self.residual if exclude is None else np.where(exclude, np.nan, self.residual)
        r = r if cols is None else r[:, cols]
        s = sigma if cols is None else sigma[cols]
        return np.nansum((r / s) ** 2, axis=1)

    def rms(self, cols=None, exclude=None):
        """Held-out residual RMS, mm, over the sensors ``cols`` (default all)."""
        r = self.residual if exclude is None else np.where(exclude, np.nan, self.residual)
        r = r if cols is None else r[:, cols]
        return float(np.sqrt(np.nanmean(r**2)))


def kfold(nominal, obs, cov, sigma, components, k, theta0):
    """k-fold-by-pose held-out figures of the base model plus ``components``."""
    p = obs.n_poses
    res = np.full(obs.d.shape, np.nan)
    dev = np.full(p, np.nan)
    for test in _folds(p, k):
        train = np.setdiff1d(np.arange(p), test)
        comps = [c.select(train) for c in components]
        f = _fit_any(nominal, obs.select(train), cov.select(train), sigma, comps, theta0)
        res[test], dev[test] = _heldout_eval(nominal, obs, cov, sigma, f, test)
    return HeldOut(res, dev)


def _fit_any(nominal, obs, cov, sigma, comps, theta0, solver="gn"):
    """Fit: sensors fitted separately when no component couples them (faster, identical)."""
    if comps:
        f = fit(nominal, obs, cov, sigma, comps, theta0=theta0, solver=solver)
        if len(f.sensors) == nominal.n:
            return f
        # the other sensors keep the base fit of this subset
        base = _fit_any(nominal, obs, cov, sigma, (), theta0, solver)
        th, se, res = base.theta.copy(), base.theta_stderr.copy(), base.residual.copy()
        S = list(f.sensors)
        th[S], se[S], res[:, S] = f.theta[S], f.theta_stderr[S], f.residual[:, S]
        return Fit(th, se, f.components, res, f.chi2 + _chi2_other(base, sigma, S), f.dof, f.sensors,
                   f.corr_base, f.corr_with, f.extra_cov)
    th = np.zeros((nominal.n, 5))
    se = np.zeros((nominal.n, 5))
    res = np.full(obs.d.shape, np.nan)
    chi2, dof = 0.0, 0
    for i in range(nominal.n):
        f = fit(nominal, obs, cov, sigma, (), sensors=[i], theta0=theta0, solver=solver)
        th[i], se[i], res[:, i] = f.theta[i], f.theta_stderr[i], f.residual[:, i]
        chi2 += f.chi2
        dof += f.dof
    return Fit(th, se, (), res, chi2, dof, tuple(range(nominal.n)))


def _chi2_other(base, sigma, S):
    other = [i for i in range(base.residual.shape[1]) if i not in S]
    r = base.residual[:, other] / sigma[other]
    return float(np.nansum(r**2))


# ---------------------------------------------------------------------------------------
# the diagnosis


def _public(d):
    return None if d is None else {k: v for k, v in d.items() if not k.startswith("_")}


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_dict` is the ``--json`` output."""

    cause: str
    sensors: list
    confidence: str
    summary: str
    named: dict | None
    candidates: list
    tests_base: dict
    tests_extended: dict | None
    structure_base: dict
    discrepancy: dict
    heldout: dict
    confounding: list
    base_theta: np.ndarray
    base_stderr: np.ndarray
    thresholds: dict
    datum_form: dict | None = None
    # for plots
    plot_data: dict = field(default_factory=dict, repr=False)

    def to_dict(self):
        return {
            "cause": self.cause, "sensors": self.sensors, "confidence": self.confidence, "summary": self.summary,
            "extended": self.named, "heldout": self.heldout, "discrepancy": self.discrepancy,
            "candidates": self.candidates, "confounding": self.confounding,
            "tests": {"base": _public(self.tests_base), "extended": _public(self.tests_extended)},
            "structure": self.structure_base,
            "base": {"theta": self.base_theta.tolist(), "stderr": self.base_stderr.tolist(),
                     "columns": ["dx_mm", "dy_mm", "dz_mm", "a_rad", "b_rad"]},
            "thresholds": self.thresholds,
            "datum_form": _public(self.datum_form),
        }


def _flag_outliers(nominal, obs, cov, sigma, theta0):
    """Robust per-sensor fit; flag |r| / s > t with t at ``alpha_outlier`` family-wise.

    ``s`` is the larger of the stated noise and the residuals' robust (MAD) scale. Returns
    (flags (p, n) bool, p-value of the largest standardised residual).
    """
    from scipy import stats

    p, n = obs.d.shape
    m = int(np.isfinite(obs.d).sum())
    z = np.full((p, n), np.nan)
    for i in range(n):
        f = fit(nominal, obs, cov, sigma, (), sensors=[i], theta0=theta0, loss="soft_l1", solver="gn")
        r = f.residual[:, i]
        mad = 1.4826 * np.nanmedian(np.abs(r - np.nanmedian(r)))
        z[:, i] = r / max(sigma[i], mad)
    zmax = float(np.nanmax(np.abs(z)))
    p_max = min(1.0, m * 2 * float(stats.norm.sf(zmax)))
    t = float(stats.norm.isf(THRESHOLDS["alpha_outlier"] / (2 * m)))
    flags = np.isfinite(z) & (np.abs(z) > t)
    return flags, p_max


def _simulated_figures(nominal, obs, cov, sigma, model: ExtendedModel, k, theta0, rng, reps, per_pose_sigma=None):
    """Simulation of this data set under ``model`` plus the stated noise, analysed with the
    base model: in-sample residual RMS per sensor (n,) mm and held-out normal deviation mean
    (rad), averaged over ``reps`` draws."""
    d_model = model.predict(obs.normal, obs.offset, cov)
    rms, ndev = [], []
    for _ in range(reps):
        d = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
        d = np.where(np.isfinite(obs.d), d, np.nan)
        o = Observations(obs.normal, obs.offset, d)
        b = _fit_any(nominal, o, cov, sigma, (), theta0)
        rms.append(np.sqrt(np.nanmean(b.residual**2, axis=0)))
        ndev.append(np.nanmean(kfold(nominal, o, cov, sigma, (), k, theta0).normal_dev))
    return np.mean(rms, axis=0), float(np.mean(ndev)), float(np.std(ndev))


def _dof_per_sensor(f: Fit, obs, n):
    cnt = np.isfinite(obs.d).sum(axis=0).astype(float)
    dof = cnt - 5
    for c in f.components:
        if c.sensors:
            for i in c.sensors:
                dof[i] -= c.n_params / len(c.sensors)
        else:
            dof -= (c.n_params - (3 if c.per_pose else len(c.constraint(c.values)[0]))) / n
    return dof


def diagnose(ds, folds: int = 5, sim_reps: int = 2, seed: int = 0) -> Diagnosis:
    """Run the full diagnosis on a :class:`~metrology.dataset.Dataset` (see the module doc).

    ``folds``: k of the k-fold by pose; ``sim_reps``: simulated copies of the data set per
    side-by-side figure; ``seed``: of the simulation's noise (the diagnosis itself is
    deterministic).
    """
    from scipy import stats

    nominal = ds.layout
    obs = ds.obs
    p, n = obs.d.shape
    if p < 2 * folds:
        raise ValueError(f"{p} poses: need at least {2 * folds} for {folds}-fold held-out figures")
    names = nominal.names
    sigma = nominal.noise_mm.copy()
    rng = np.random.default_rng(seed)
    # 1. base calibration (per sensor) with covariates at the nominal geometry, then recomputed
    cov0 = covariates_for(ds, nominal)
    sig_fit = np.where(np.isfinite(sigma), sigma, 1.0)
    base0 = _fit_any(nominal, obs, cov0, sig_fit, (), None, "lsq")
    if not np.all(np.isfinite(sigma)):  # no stated noise: the base fit's own scatter
        sigma = np.where(np.isfinite(sigma), sigma, np.sqrt(np.nanmean(base0.residual**2, axis=0)))
    zero, u = _geometry(nominal, base0.theta)
    calibrated = nominal.with_params(zero, u)
    cov = covariates_for(ds, calibrated)
    theta0 = base0.theta
    base = _fit_any(nominal, obs, cov, sigma, (), theta0, "lsq")
    d0_base = readings(zero, u, obs.normal, obs.offset)[0]
    dof_base = np.isfinite(obs.d).sum(axis=0) - 5
    tests_base = noise_tests(base.residual, sigma, dof_base, names)
    struct = structure(base.residual, d0_base, cov, names)
    ho_base = kfold(nominal, obs, cov, sigma, (), folds, theta0)
    datum = None if ds.datum_points is None else datum_form(ds, zero, u, obs, cov, d0_base, sigma)

    # 2. candidates
    flags, p_out = _flag_outliers(nominal, obs, cov, sigma, theta0)
    cands = candidates_for(nominal, cov, flags)
    n_cand = len(cands)
    scored = []
    for c in cands:
        f = _fit_any(nominal, obs, cov, sigma, (c,), theta0)
        k = c.n_params - (3 if c.per_pose else len(c.constraint(c.values)[0]))
        S = list(f.sensors)
        chi2_b = float(np.nansum((base.residual[:, S] / sigma[S]) ** 2))
        chi2_e = float(np.nansum((f.residual[:, S] / sigma[S]) ** 2))
        m_S = int(np.isfinite(obs.d[:, S]).sum())
        dof_e = m_S - 5 * len(S) - k
        if isinstance(c, Outliers):
            p_in = p_out  # selection by the largest residual: its own test
        else:
            F = ((chi2_b - chi2_e) / k) / max(chi2_e / max(dof_e, 1), 1e-300)
            p_in = float(stats.f.sf(F, k, max(dof_e, 1)))
        ho = kfold(nominal, obs, cov, sigma, (c,), folds, theta0)
        excl = flags if isinstance(c, Outliers) else None
        cb = ho_base.chi2_pose(sigma, exclude=excl)
        ce = ho.chi2_pose(sigma, exclude=excl)
        diff = cb - ce  # all sensors: comparable between candidates (ranking)
        diff_S = ho_base.chi2_pose(sigma, S, excl) - ho.chi2_pose(sigma, S, excl)  # its sensors: the test
        if np.allclose(diff_S, 0):
            p_ho = 1.0
        else:
            p_ho = float(stats.ttest_1samp(diff_S, 0.0, alternative="greater").pvalue)
        rb, re_ = ho_base.rms(S, excl), ho.rms(S, excl)
        nb_, ne_ = float(np.nanmean(ho_base.normal_dev)), float(np.nanmean(ho.normal_dev))
        sig = (p_in < THRESHOLDS["alpha_candidates"] / n_cand) and (p_ho < THRESHOLDS["alpha_heldout"]) and rb > re_
        scored.append({
            "label": c.label, "cause": c.name, "sensors": [names[i] for i in c.sensors], "n_params": k,
            "p_insample": p_in, "p_heldout": p_ho, "heldout_chi2_reduction": float(np.sum(diff)),
            "heldout_rms_base_mm": rb, "heldout_rms_extended_mm": re_, "heldout_rms_ratio": rb / re_,
            "heldout_normal_base_deg": float(np.rad2deg(nb_)), "heldout_normal_extended_deg": float(np.rad2deg(ne_)),
            "significant": bool(sig), "_fit": f, "_ho": ho, "_comp": c, "_ce": ce,
        })
    sig_list = sorted([s for s in scored if s["significant"]], key=lambda s: -s["heldout_chi2_reduction"])
    # the strongest candidate significant in sample only: a lead, never a name
    in_only = sorted([s for s in scored if not s["significant"] and s["p_insample"] < THRESHOLDS["alpha_candidates"] / n_cand],
                     key=lambda s: s["p_insample"])
    lead = in_only[0] if in_only else None

    # decision
    named = None
    tests_ext = None
    confounding = []
    best = sig_list[0] if sig_list else None
    if best is not None and best["cause"] == "drift" and best["_comp"].variable == "time":
        # tie-break: temperature is the physical cause, time its proxy; prefer it when the
        # data cannot tell the two apart
        for other in sig_list[1:]:
            oc = other["_comp"]
            if oc.name == "drift" and oc.variable == "temp" and oc.sensors == best["_comp"].sensors:
                d = other["_ce"] - best["_ce"]
                p_sep = float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue) if not np.allclose(d, 0) else 1.0
                if p_sep >= THRESHOLDS["alpha_confound"]:
                    sig_list.remove(other)
                    sig_list.insert(0, other)
                    best = other
                break
    if best is None:
        cause = "none" if tests_base["consistent"] else "unexplained"
        confidence = "high" if tests_base["consistent"] and lead is None else "low"
        sensors = []
    else:
        best["_fit"] = _fit_any(nominal, obs, cov, sigma, (best["_comp"],), theta0, "lsq")
        f = best["_fit"]
        # a per-pose component makes the sensors of a pose correlated by construction
        tests_ext = noise_tests(f.residual, sigma, _dof_per_sensor(f, obs, n), names,
                                pairs=not any(c.per_pose for c in f.components))
        concerned = list(f.sensors)
        p_concerned = battery_on(tests_ext, concerned)
        tests_ext["p_concerned"] = p_concerned
        if p_concerned >= THRESHOLDS["alpha_battery"]:
            cause, sensors = best["cause"], best["sensors"]
            # its own sensors are explained; others that still fail are a separate matter
            confidence = "high" if tests_ext["consistent"] else "partial"
        else:
            cause, confidence = "unexplained", "low"
            sensors = []
        # runner-ups that explain as much (a different cause or sensor)
        for other in sig_list[1:]:
            if other["cause"] == best["cause"] and other["sensors"] == best["sensors"]:
                continue
            d = other["_ce"] - best["_ce"]
            p_sep = float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue) if not np.allclose(d, 0) else 1.0
            if p_sep >= THRESHOLDS["alpha_confound"]:
                confounding.append({
                    "between": [best["label"], other["label"]], "p_separation": p_sep,
                    "message": f"the data cannot tell {best['label']} from {other['label']} (held-out gains "
                               f"indistinguishable, p = {p_sep:.2g}); to separate them: "
                               f"{ADVICE[best['cause']]}; {ADVICE[other['cause']]}",
                })
        fc = f.components[0]
        for q, (cb_, w) in enumerate(zip(f.corr_base, f.corr_with)):
            if cb_ > THRESHOLDS["corr_confound"]:
                confounding.append({
                    "between": [f"{fc.label}.{fc.param_names[q]}", w], "correlation": float(cb_),
                    "message": f"{fc.label}.{fc.param_names[q]} is {cb_:.3f} correlated with the base parameter "
                               f"{w}: it is poorly separated from the geometry; {ADVICE[fc.name]} would separate them",
                })
        if confounding and confidence == "high":
            confidence = "ambiguous"
        named = _describe_named(best, f, nominal, obs, cov, sigma, rng)

    # 3-4. side by side and held-out gains
    base_model = ExtendedModel(calibrated, ())
    sim_rms_b, sim_nd_b, sim_nd_b_sd = _simulated_figures(nominal, obs, cov, sigma, base_model, folds, theta0, rng, sim_reps)
    meas_rms = np.sqrt(np.nanmean(base.residual**2, axis=0))
    discrepancy = {
        "sensors": list(names),
        "stated_noise_mm": sigma.tolist(),
        "measured_residual_rms_mm": meas_rms.tolist(),
        "simulated_base_residual_rms_mm": sim_rms_b.tolist(),
        "measured_heldout_normal_deg": float(np.rad2deg(np.nanmean(ho_base.normal_dev))),
        "simulated_base_heldout_normal_deg": float(np.rad2deg(sim_nd_b)),
        "simulated_base_heldout_normal_sd_deg": float(np.rad2deg(sim_nd_b_sd)),
        "sim_reps": sim_reps,
    }
    heldout = {"folds": folds, "base_rms_mm": ho_base.rms(), "base_normal_deg": float(np.rad2deg(np.nanmean(ho_base.normal_dev)))}
    if best is not None:
        fm = best["_fit"].model(nominal)
        sim_rms_e, sim_nd_e, sim_nd_e_sd = _simulated_figures(nominal, obs, cov, sigma, fm, folds, theta0, rng, sim_reps)
        discrepancy["simulated_extended_residual_rms_mm"] = sim_rms_e.tolist()
        discrepancy["simulated_extended_heldout_normal_deg"] = float(np.rad2deg(sim_nd_e))
        discrepancy["simulated_extended_heldout_normal_sd_deg"] = float(np.rad2deg(sim_nd_e_sd))
        discrepancy["extended_model"] = best["label"]
        ho_e = best["_ho"]
        excl = flags if best["cause"] == "outliers" else None
        S = list(best["_fit"].sensors)
        heldout.update({
            "model": best["label"],
            "base_rms_mm": ho_base.rms(None, excl), "extended_rms_mm": ho_e.rms(None, excl),
            "rms_ratio": ho_base.rms(None, excl) / ho_e.rms(None, excl),
            "base_rms_concerned_mm": ho_base.rms(S, excl), "extended_rms_concerned_mm": ho_e.rms(S, excl),
            "rms_ratio_concerned": ho_base.rms(S, excl) / ho_e.rms(S, excl),
            "extended_normal_deg": float(np.rad2deg(np.nanmean(ho_e.normal_dev))),
            "normal_ratio": float(np.nanmean(ho_base.normal_dev) / np.nanmean(ho_e.normal_dev)),
            "p_heldout": best["p_heldout"],
        })
    summary = _summary(cause, confidence, best, tests_base, tests_ext, lead)
    if datum is not None:
        # the readings' own form against the cloud's: plane_form fitted together with the named
        # cause (a pose error, say, correlates the sensors of a pose; a form fitted without it
        # would carry standard errors too small for the comparison)
        if cause == "plane_form":
            pf = best["_fit"]
        elif cause in VERDICTS:  # nothing named: the plane_form candidate's own fit
            pf = next(s["_fit"] for s in scored if s["cause"] == "plane_form")
        else:
            comps = [PlaneForm((), names=names), replace(best["_comp"], values=None, stderr=None)]
            pf = _fit_any(nominal, obs, cov, sigma, comps, theta0)
        datum["against_readings"] = _form_agreement(datum, pf)
        datum["against_readings"]["fitted_with"] = [c.label for c in pf.components]
        if not datum["against_readings"]["agree"]:
            if cause in ("none", "plane_form"):
                confidence = "low"  # the inputs contradict each other on the datum
            summary += (f"; the datum cloud's form disagrees with the readings' (p = {datum['against_readings']['p']:.2g}): "
                        "the datum changed between scan and run, or the cloud is not of the surface the beams saw")
    public = [{k: v for k, v in s.items() if not k.startswith("_")} for s in scored]
    public.sort(key=lambda s: -s["heldout_chi2_reduction"])
    plot = {"base": base, "cov": cov, "d0": d0_base, "best": best, "names": names, "sigma": sigma,
            "flags": flags, "structure": struct}
    return Diagnosis(cause, sensors, confidence, summary, named, public, tests_base, tests_ext, struct, discrepancy,
                     heldout, confounding, base.theta, base.theta_stderr, dict(THRESHOLDS), datum, plot)


#: the datum form's quadratic coefficients (bow, saddle, twist), compared cloud against readings
FORM_QUADRATIC = ("b_ss_mm", "b_st_mm", "b_tt_mm")
#: fewest cloud points under the spots' footprint to fit the form there (else the whole cloud)
MIN_FORM_POINTS = 50


def datum_form(ds, zero, u, obs, cov: Covariates, d0, sigma) -> dict:
    """The datum's form measured by the tracker cloud, and what it would do to the readings.

    The cloud is an independent measurement of the surface the beams see:
    :meth:`~metrology.effects.PlaneForm.from_cloud` in the axes of the readings' covariates,
    fitted to the points under the spots' footprint (the box of their in-plane positions;
    the whole cloud if fewer than :data:`MIN_FORM_POINTS` fall in it), because form beyond
    quadratic gives other quadratic coefficients on other regions of a real plate.
    Its quadratic part (bow, saddle, twist) is tested against zero (Wald, chi-square with 3
    dof) and evaluated at this run's spots; ``visible_rms_mm`` is the part of that term the
    base geometry cannot absorb (per sensor, the residual of its least-squares projection on
    the base Jacobian), i.e. the misfit the form would leave in the base residuals.

    zero : (n, 3) float, mm, TCS, u : (n, 3) float, unit, TCS: the base calibration;
    d0 : (p, n) float, mm, its readings; sigma : (n,) float, mm.
    """
    from scipy import stats

    from metrology.core.plane import plane_basis

    pts = ds.datum_points
    centre = np.mean(pts, axis=0)
    # only the part of the datum the beams saw: form beyond quadratic gives other quadratic
    # coefficients on other regions of a real plate
    st = (pts - centre) @ plane_basis(ds.plane.normal).T
    spots = cov.spot_st[np.isfinite(obs.d)]
    under = np.all((st >= spots.min(axis=0)) & (st <= spots.max(axis=0)), axis=1)
    window = "under the spots" if under.sum() >= MIN_FORM_POINTS else "whole cloud"
    if window == "whole cloud":
        under = np.ones(len(pts), bool)
    form, C = PlaneForm.from_cloud(pts[under], ds.plane.normal, ds.plane.offset, centre, names=ds.layout.names)
    q, Cq = form.values[2:], C[2:, 2:]
    wald = float(q @ np.linalg.lstsq(Cq, q, rcond=None)[0])
    quad = form.with_values(np.r_[0.0, 0.0, q])
    term = quad.evaluate(quad.values, d0, cov)
    J = jacobian_raw(zero, u, obs.normal, obs.offset)
    visible = []
    for i in range(term.shape[1]):
        ok = np.isfinite(obs.d[:, i]) & np.isfinite(term[:, i])
        r = term[ok, i] - J[ok, i] @ np.linalg.lstsq(J[ok, i], term[ok, i], rcond=None)[0]
        visible.append(float(np.sqrt(np.mean(r**2))) if ok.any() else float("nan"))
    params = form.describe()["params"]
    return {
        "points": int(len(pts)), "points_used": int(under.sum()), "window": window,
        "window_mm": {"s": [float(spots[:, 0].min()), float(spots[:, 0].max())],
                      "t": [float(spots[:, 1].min()), float(spots[:, 1].max())]},
        "radius_mm": form.radius_mm, "params": params,
        "p_quadratic": float(stats.chi2.sf(wald, 3)), "_values": form.values, "_cov": C,
        "visible_rms_mm": visible, "visible_over_noise": [v / s for v, s in zip(visible, sigma)],
    }


def _form_agreement(datum: dict, readings_fit: Fit) -> dict:
    """Quadratic coefficients of the cloud against those of the ``plane_form`` fitted to the
    readings: per coefficient the difference in combined standard errors, and the Wald
    chi-square (3 dof, both full covariances) with its p-value; ``agree`` at ``alpha_form``."""
    from scipy import stats

    off = 0
    for comp in readings_fit.components:  # extra_cov covers the components not per pose, in order
        if isinstance(comp, PlaneForm):
            break
        off += 0 if comp.per_pose else comp.n_params
    idx = [comp.param_names.index(k) for k in FORM_QUADRATIC]
    v_r = comp.values[idx]
    C_r = readings_fit.extra_cov[np.ix_([off + i for i in idx], [off + i for i in idx])]
    v_c, C_c = datum["_values"][2:], datum["_cov"][2:, 2:]
    diff = v_r - v_c
    Cd = C_r + C_c
    z = diff / np.sqrt(np.diag(Cd))
    wald = float(diff @ np.linalg.solve(Cd, diff))
    p = float(stats.chi2.sf(wald, 3))
    return {"readings": dict(zip(FORM_QUADRATIC, v_r.tolist())),
            "readings_stderr": dict(zip(FORM_QUADRATIC, np.sqrt(np.diag(C_r)).tolist())),
            "z": dict(zip(FORM_QUADRATIC, z.tolist())), "chi2": wald, "p": p,
            "agree": bool(p >= THRESHOLDS["alpha_form"])}


#: simulated noise-only copies used to measure the noise floor of the per-pose estimates
POSE_FLOOR_REPS = 8


def _describe_named(best, f: Fit, nominal, obs, cov, sigma, rng):
    comp = f.components[0]
    d = comp.describe()
    if isinstance(comp, PoseError):
        # sigma of the pose error along the normal: the spread of the per-pose estimates less
        # the spread that reading noise alone puts in them (through the per-pose fit and the
        # base parameters it trades with), measured on noise-only simulations of these poses
        e = comp.values
        model = replace(f.model(nominal), components=())
        d_model = model.predict(obs.normal, obs.offset, cov)

        def estimate(e_sim):
            """sigma-hat of noise-only copies (the floor) or copies with per-pose errors ``e_sim``."""
            vals = []
            for _ in range(POSE_FLOOR_REPS):
                dn = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
                if e_sim is not None:
                    dn = dn + rng.normal(0.0, e_sim, len(dn))[:, None] * cov.inv_nu
                dn = np.where(np.isfinite(obs.d), dn, np.nan)
                fn = fit(nominal, Observations(obs.normal, obs.offset, dn), cov, sigma, [replace(comp, values=None)],
                         theta0=f.theta, solver="gn")
                vals.append(np.var(fn.components[0].values, ddof=1))
            return np.array(vals)

        v_floor = float(np.mean(estimate(None)))
        sig_raw = np.sqrt(max(float(np.var(e, ddof=1)) - v_floor, 0.0))
        # parametric bootstrap: the spread of the per-pose estimates also takes up weakly
        # identified base-parameter combinations; re-estimate on copies with pose errors of the
        # estimated size, correct the bias and take their scatter as the standard error
        boot = np.sqrt(np.maximum(estimate(sig_raw) - v_floor, 0.0))
        sig_e = max(sig_raw - (float(np.mean(boot)) - sig_raw), 0.0)
        d["params"] = {"sigma_mm": {"value": sig_e, "unit": "mm", "stderr": float(np.std(boot, ddof=1))},
                       "noise_floor_mm": {"value": float(np.sqrt(v_floor)), "unit": "mm", "stderr": None}}
        d["per_pose_mm"] = e.tolist()
    if isinstance(comp, Outliers):
        d["flagged"] = [{"pose": int(pp), "sensor": comp.names[i], "gross_mm": float(v), "stderr": float(s)}
                        for (pp, i), v, s in zip(comp.cells, comp.values, comp.stderr)]
        d["params"] = {"count": {"value": len(comp.cells), "unit": "1", "stderr": None}}
    d["base_correlation"] = [{"param": comp.param_names[q], "max_abs_corr": float(c), "with": w}
                             for q, (c, w) in enumerate(zip(f.corr_base, f.corr_with))]
    return d


def _summary(cause, confidence, best, tb, te, in_only=None):
    """One paragraph of the verdict; ``in_only`` is the strongest candidate significant in
    sample only (its held-out gain not), reported as a lead when nothing is named."""
    worst = max(tb["sensors"].items(), key=lambda kv: kv[1]["chi2"] / kv[1]["dof"])
    lead = ""
    if in_only is not None:
        lead = (f"; {in_only['label']} fits in sample (p = {in_only['p_insample']:.2g}) but does not predict held-out "
                f"poses significantly better (p = {in_only['p_heldout']:.2g}, RMS ratio "
                f"{in_only['heldout_rms_ratio']:.3g}): too small, or too confounded, to name")
    if cause == "none":
        return (f"residuals consistent with the stated noise (battery p = {tb['p_bonferroni']:.2g}); "
                "no candidate gives a significant held-out gain" + lead)
    if best is None:
        return (f"residuals inconsistent with the noise model (battery p = {tb['p_bonferroni']:.2g}, worst "
                f"{worst[0]}: sigma {worst[1]['sigma_est_mm']:.4g} mm) and no catalogued effect gives a "
                "significant held-out gain" + lead)
    if cause == "unexplained":
        return (f"{best['label']} gives a significant held-out gain (RMS ratio {best['heldout_rms_ratio']:.3g}) but "
                f"leaves the residuals of its sensors inconsistent with the noise model (battery p = "
                f"{te['p_concerned']:.2g}): a partial explanation at best")
    text = (f"{best['label']}: held-out RMS ratio {best['heldout_rms_ratio']:.3g} on its sensors (p = "
            f"{best['p_heldout']:.2g}), its sensors' residuals then consistent with noise (p = {te['p_concerned']:.2g})")
    if not te["consistent"]:
        text += (f"; other residuals remain inconsistent (battery p = {te['p_bonferroni']:.2g}): another effect, "
                 "or a false alarm of the tests")
    return text + f"; confidence {confidence}"


def diagnose_files(export_path, plane_path, layout_path, **kw) -> Diagnosis:
    """:func:`diagnose` on the three files of a run (see :func:`metrology.dataset.load_dataset`)."""
    from metrology.calibration.dataset import load_dataset

    ds = load_dataset(export_path, plane_path, layout_path)
    return diagnose(ds, **kw)


def plot_report(diag: Diagnosis, out_dir) -> list:
    """Residual plots that made the case, before and after; returns the files written."""
    from pathlib import Path

    from metrology.report.plots import pyplot

    plt = pyplot()

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    P = diag.plot_data
    base, cov, names, d0 = P["base"], P["cov"], P["names"], P["d0"]
    files = []
    p, n = base.residual.shape
    variables = {
        "d_mm": d0, "incidence_deg": np.rad2deg(np.arccos(np.clip(cov.cos_inc, -1, 1))),
        "time_h": np.broadcast_to(cov.time_h[:, None], (p, n)), "temp_c": np.broadcast_to(cov.temp_c[:, None], (p, n)),
        "spot_s_mm": cov.spot_st[..., 0], "spot_t_mm": cov.spot_st[..., 1],
        "pose_index": np.broadcast_to(np.arange(p, dtype=float)[:, None], (p, n)),
    }
    variables = {k: v for k, v in variables.items() if np.all(np.isfinite(v))}
    # overview: base residuals against every covariate
    fig, axes = plt.subplots(n, len(variables), figsize=(2.6 * len(variables), 2.0 * n), squeeze=False, sharey="row")
    for i in range(n):
        for j, (key, X) in enumerate(variables.items()):
            ax = axes[i, j]
            ax.plot(X[:, i], base.residual[:, i] * 1e3, ".", ms=3)
            ax.axhline(0, color="k", lw=0.5)
            if i == n - 1:
                ax.set_xlabel(key)
            if j == 0:
                ax.set_ylabel(f"{names[i]} residual um")
    fig.suptitle("base model: residuals against each variable")
    fig.tight_layout()
    f1 = out / "residuals_base.png"
    fig.savefig(f1, dpi=90)
    plt.close(fig)
    files.append(str(f1))
    best = P["best"]
    if best is not None:
        f = best["_fit"]
        comp = f.components[0]
        key = {"scale": "d_mm", "nonlinearity": "d_mm", "incidence": "incidence_deg", "plane_form": "spot_s_mm",
               "pose_error": "pose_index", "outliers": "pose_index"}.get(comp.name)
        if comp.name == "drift":
            key = "temp_c" if comp.variable == "temp" else "time_h"
        cols = list(comp.sensors) if comp.sensors else list(range(n))
        fig, axes = plt.subplots(len(cols), 2, figsize=(9, 2.4 * len(cols)), squeeze=False, sharey="row")
        X = variables.get(key, variables["pose_index"])
        term = comp.evaluate(comp.values, d0, cov)
        for r, i in enumerate(cols):
            a0, a1 = axes[r]
            a0.plot(X[:, i], base.residual[:, i] * 1e3, ".", ms=3, label="base residual")
            order = np.argsort(X[:, i])
            if comp.name not in ("pose_error", "outliers"):
                a0.plot(X[order, i], (term[order, i] - np.nanmean(term[:, i]) + np.nanmean(base.residual[:, i])) * 1e3,
                        "-", color="C3", label=f"fitted {comp.name}")
            a1.plot(X[:, i], f.residual[:, i] * 1e3, ".", ms=3, color="C2")
            for a in (a0, a1):
                a.axhline(0, color="k", lw=0.5)
                a.set_xlabel(key)
            a0.set_ylabel(f"{names[i]} um")
            a0.set_title("before (base)" if r == 0 else "")
            a1.set_title(f"after ({comp.label})" if r == 0 else "")
            a0.legend(fontsize=7)
        fig.tight_layout()
        f2 = out / "residuals_named.png"
        fig.savefig(f2, dpi=90)
        plt.close(fig)
        files.append(str(f2))
    return files

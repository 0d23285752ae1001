"""The extended fit: the base model plus effect components, by least squares.

:func:`fit` solves with ``scipy.optimize.least_squares`` or its own Gauss-Newton
(:func:`gauss_newton`, the same minimum, faster inside the k-fold loops); :func:`fit_any` fits
the sensors separately when no component couples them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.core.effects import Covariates, ExtendedModel
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, direction_from_tangent, jacobian_raw, readings
from metrology.core.observations import Observations
from metrology.diagnosis.memo import memoised
from metrology.diagnosis.stats import NoiseTests, battery_rng, noise_tests

__all__ = ["Fit", "fit", "fit_any", "gauss_newton", "geometry", "dof_per_sensor", "judged_residuals", "residual_battery"]


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



def geometry(nominal, theta):
    """Zero points ``(n, 3)`` mm TCS and unit directions ``(n, 3)`` TCS of the chart errors
    ``theta (n, 5)`` around ``nominal``."""
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


def _project_per_pose_multi(Bw, X, Bpinv=None):
    """Remove each pose's own columns: ``X - Bw e`` with ``e = Bw_p^+ X_p`` per pose.

    Bw : (p, s, m) float, each pose's columns (zero where no reading); X : (p, s) or (p, s, k);
    Bpinv : (p, m, s) float, ``pinv(Bw)`` if already computed. The directions these share with
    the base geometry (a rigid motion of the whole head) are left to the solver's
    rank-revealing step. Returns (projected X, e (p, m) or (p, m, k)).
    """
    squeeze = X.ndim == 2
    Xk = X[..., None] if squeeze else X
    Bpinv = np.linalg.pinv(Bw, rcond=1e-10) if Bpinv is None else Bpinv
    e = Bpinv @ Xk  # (p, m, k)
    out = Xk - Bw @ e
    return (out[..., 0], e[..., 0]) if squeeze else (out, e)


#: weight of the rigid-head gauge rows (whitened residual units per unit of the normalised mode)
RIGID_GAUGE_WEIGHT = 1e3


#: a column whose norm the per-pose projection leaves below this share of its own is absorbed (zeroed)
ABSORBED_COLUMN_RTOL = 1e-8


#: singular values of the projected base Jacobian below this share of the largest are held
ABSORBED_RTOL = 1e-3


def _absorbed_modes(Jp) -> np.ndarray:
    """``(g, nb)``: the unit directions of the base parameters that per-pose values absorb, from
    the base Jacobian ``Jp (rows, nb)`` with each pose's own columns projected out.

    A per-pose offset and two tilts absorb a rigid motion of the whole head exactly (6
    directions), and more: any change of the geometry whose reading changes are, pose by pose,
    an affine function of the spot positions (a scaling of the zero points, for one). On the
    bundled 100-pose data set (``metrology/data/measured``) 8 directions are exactly absorbed and
    4 more only to 1e-4 of the largest singular value; with the 6 rigid-head directions alone
    held, the fit wandered 21 mm along the others. All of them are held (gauge rows).
    """
    if Jp.shape[1] == 0:
        return np.zeros((0, 0))
    _, sv, vt = np.linalg.svd(Jp, full_matrices=False)
    return vt[sv < ABSORBED_RTOL * sv[0]]


def _fit_key(nominal, obs, cov, sigma, components=(), sensors=None, theta0=None, loss="linear", solver="lsq",
             covariance=True):
    """What :func:`fit`'s result depends on (its key in :func:`~metrology.diagnosis.memo.memoised`)."""
    return (nominal.names, nominal.zero, nominal.direction, obs, cov, np.asarray(sigma, float), tuple(components),
            None if sensors is None else tuple(int(i) for i in sensors),
            None if theta0 is None else np.asarray(theta0, float), loss, solver, bool(covariance))


@memoised(_fit_key)
def fit(nominal: SensorLayout, obs: Observations, cov: Covariates, sigma, components=(), sensors=None,
        theta0=None, loss="linear", solver="lsq", covariance=True) -> Fit:
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
    covariance : bool, compute the standard errors, correlations and ``extra_cov`` (False: a
        fit whose residuals and values alone are wanted, as the k-fold's; those are then zero,
        empty or None)

    A per-pose component (:class:`~metrology.effects.PoseError`) is profiled out exactly:
    its basis does not depend on the parameters, so for any base parameters the optimal
    per-pose values are a fixed linear map of the residual (variable projection); its values
    are then recovered with standard errors ``s / ||b_p||`` (reading noise only).

    Results are kept by the content of the inputs (:mod:`metrology.diagnosis.memo`): the same
    fit asked for again is not computed again, and its arrays are read-only.
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
    # a per-pose rigid error (offset and two tilts a pose) leaves one reading in four to the
    # geometry; scored, it holds the base parameters at ``theta0`` (the base calibration)
    hold = any(getattr(c, "holds_base", False) for c in comps)
    nb = 0 if hold else 5 * len(S)
    x0 = np.concatenate([np.zeros(0) if hold else theta0[S].ravel()] + [c.values for c in free])
    zero_all, u_all = geometry(nominal, theta0)
    d_full0 = readings(zero_all, u_all, N, D)[0]
    basis0 = direction_basis(nominal.direction[S])
    u0S = nominal.direction[S]
    u0n = u0S / np.linalg.norm(u0S, axis=1, keepdims=True)  # the Jacobian's chart (as jacobian_tangent)
    basis_n = direction_basis(u0n)
    # a term that does not depend on d0 has the same basis at every step: computed once
    fixed = [None if c.uses_d0 else c.basis(d_full0, cov) for c in free]
    last = [None, None]  # the last predict's x (bytes) and result: fun and jac ask at the same x
    Bw = None
    if prof:
        Bw = np.where(ok[..., None], prof[0].pose_columns(cov)[:, S, :] / sig[None, :, None], 0.0)  # (p, s, m)
        Bpinv = np.linalg.pinv(Bw, rcond=1e-10) if Bw.shape[2] > 1 else None

    G = None  # gauge rows: the geometry the per-pose offsets and tilts absorb (see _absorbed_modes)

    def project(X):
        if Bw.shape[2] == 1:  # an offset a pose: the gauge of the zero points, exactly
            return _project_per_pose(Bw[..., 0], X, N)
        return _project_per_pose_multi(Bw, X, Bpinv)

    def unpack(x):
        th = theta0.copy()
        if not hold:
            th[S] = x[:nb].reshape(-1, 5)
        vals, j = [], nb
        for k in k_comp:
            vals.append(x[j:j + k])
            j += k
        return th, vals

    def predict(x):
        key = x.tobytes()
        if last[0] == key:
            return last[1]
        th, vals = unpack(x)
        w = u0S + np.einsum("nk,nkj->nj", th[S, 3:], basis0)
        d0s, _ = readings(nominal.zero[S] + th[S, :3], w, N, D)
        d0 = d_full0.copy()
        d0[:, S] = d0s
        f = np.zeros_like(d0)
        bases = [c.basis(d0, cov) if B is None else B for c, B in zip(free, fixed)]
        for B, v in zip(bases, vals):
            f += B @ np.asarray(v, float)  # Component.evaluate: every catalogued term is linear in its values
        last[0], last[1] = key, (th, vals, d0, f, bases)
        return last[1]

    def residual_matrix(x):
        th, vals, d0, f, _ = predict(x)
        R = np.where(ok, (dS - d0[:, S] - f[:, S]) / sig, 0.0)
        e = None
        if Bw is not None:
            R, e = project(R)
        return R, e, th, vals, d0

    def fun(x):
        R, _, th, vals, _ = residual_matrix(x)
        extra = [c.constraint(v)[0] for c, v in zip(free, vals)]
        if G is not None:
            extra.append(G @ (x[:nb] - x0[:nb]))
        return np.concatenate([R[ok]] + extra)

    def jac(x):
        th, vals, d0, f, bases = predict(x)
        # jacobian_tangent with its chart computed once
        J6 = jacobian_raw(nominal.zero[S] + th[S, :3], u0n + np.einsum("nk,nkj->nj", th[S, 3:], basis_n), N, D)
        J0 = np.concatenate([J6[..., :3], np.einsum("pnj,nkj->pnk", J6[..., 3:], basis_n)], axis=-1)  # (p, s, 5)
        g = np.ones_like(d0)
        for c, v in zip(free, vals):
            if c.uses_d0:
                g += c.d_dd0(v, d0, cov)
        J0 = J0 * g[:, S, None]
        p, s = ok.shape
        Jb = np.zeros((p, s, nb))
        for a in range(s if nb else 0):
            Jb[:, a, 5 * a:5 * a + 5] = J0[:, a]
        blocks = [Jb] + [B[:, S] for B in bases]  # Component.jacobian: the basis
        Jr = -np.concatenate(blocks, axis=-1) / sig[None, :, None]
        Jr = np.where(ok[..., None], Jr, 0.0)
        if Bw is not None:
            n0 = np.sqrt(np.einsum("psk,psk->k", Jr, Jr))
            Jr, _ = project(Jr)
            # a column the per-pose values absorb (a datum tilt under an offset and two tilts a
            # pose) is left as rounding noise: zero it, or the column scaling blows it up
            gone = np.sqrt(np.einsum("psk,psk->k", Jr, Jr)) <= ABSORBED_COLUMN_RTOL * n0
            Jr[..., gone] = 0.0
        rows = [Jr[ok]]
        off = nb
        for c, v, k in zip(free, vals, k_comp):
            Jc = c.constraint(v)[1]
            if len(Jc):
                Rr = np.zeros((len(Jc), rows[0].shape[1]))
                Rr[:, off:off + k] = Jc
                rows.append(Rr)
            off += k
        if G is not None:
            Rr = np.zeros((len(G), rows[0].shape[1]))
            Rr[:, :nb] = G
            rows.append(Rr)
        return np.concatenate(rows, axis=0)

    n_gauge = 0 if not prof else prof[0].gauge_dof
    if prof and prof[0].per_pose_columns > 1 and not hold:
        G = _absorbed_modes(jac(x0)[:, :nb]) * RIGID_GAUGE_WEIGHT
        n_gauge = len(G)
    if x0.size == 0:
        x = x0
    elif solver == "lsq":
        kw = {} if loss == "linear" else {"loss": loss, "f_scale": 1.0}
        x = least_squares(fun, x0, jac=jac, method="trf", x_scale="jac", **kw).x
    elif solver == "gn":
        x = gauss_newton(fun, jac, x0, loss)
    else:
        raise ValueError(f"solver must be 'lsq' or 'gn', got {solver!r}")
    R, e, th, vals, d0 = residual_matrix(x)
    f = predict(x)[3]
    res = np.full(obs.d.shape, np.nan)
    res[:, S] = np.where(ok, R * sig, np.nan)
    others = np.setdiff1d(np.arange(n), S)
    res[:, others] = obs.d[:, others] - d_full0[:, others] - f[:, others]
    rS = R[ok]
    m = rS.size
    k = nb + sum(k_comp) - sum(len(c.constraint(v)[0]) for c, v in zip(free, vals)) + (e.size - (0 if hold else n_gauge) if e is not None else 0)
    dof = m - k
    chi2 = float(np.sum(rS**2))
    if not covariance:
        it_free = iter(vals)
        out = [c.with_values(e.ravel()) if c.per_pose else c.with_values(next(it_free)) for c in comps]
        return Fit(th, np.zeros((n, 5)), tuple(out), res, chi2, int(dof), tuple(int(i) for i in S))
    s2 = chi2 / max(dof, 1)
    J = jac(x)
    # covariance s^2 (J^T J)^-1, column-scaled normal equations (small: base + few extras)
    scale = np.linalg.norm(J, axis=0)
    scale = np.where(scale > 0, scale, 1.0)  # an absorbed (zeroed) column: no information, no scale
    Js = J / scale
    C = np.linalg.pinv(Js.T @ Js, rcond=1e-12, hermitian=True) / np.outer(scale, scale) * s2
    se = np.sqrt(np.maximum(np.diag(C), 0.0))
    theta_se = np.zeros((n, 5))
    if not hold:
        theta_se[S] = se[:nb].reshape(-1, 5)
    out, j = [], nb
    corr_b, corr_w = [], []
    base_names = [f"{nominal.names[i]}.{q}" for i in S for q in ("x", "y", "z", "a", "b")]
    it_free = iter(zip(free, vals))
    for c in comps:
        if c.per_pose:
            BtB = np.einsum("psm,psq->pmq", Bw, Bw)
            var = np.diagonal(np.linalg.pinv(BtB, rcond=1e-10, hermitian=True), axis1=1, axis2=2)  # (p, m)
            out.append(c.with_values(e.ravel(), np.sqrt(s2 * np.maximum(var, 0.0)).ravel()))
            continue
        c2, v = next(it_free)
        kk = c2.n_params
        out.append(c2.with_values(v, se[j:j + kk]))
        for q in range(kk):
            if hold:  # the base parameters are held: no correlation with them
                corr_b.append(0.0)
                corr_w.append("held")
                continue
            cc = C[j + q, :nb] / np.maximum(se[j + q] * se[:nb], 1e-300)
            a = int(np.argmax(np.abs(cc)))
            corr_b.append(float(np.abs(cc[a])))
            corr_w.append(base_names[a])
        j += kk
    return Fit(th, theta_se, tuple(out), res, chi2, int(dof), tuple(int(i) for i in S), np.array(corr_b),
               tuple(corr_w), C[nb:, nb:])


def gauss_newton(fun, jac, x0, loss, max_iter=30, tol=1e-10):
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
        scale = np.linalg.norm(Jw, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
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


def fit_any(nominal, obs, cov, sigma, comps, theta0, solver="gn", covariance=True) -> Fit:
    """:func:`fit`, with the sensors fitted separately when no component couples them (faster,
    identical); ``covariance`` as :func:`fit`'s."""
    if comps:
        f = fit(nominal, obs, cov, sigma, comps, theta0=theta0, solver=solver, covariance=covariance)
        if len(f.sensors) == nominal.n:
            return f
        # the other sensors keep the base fit of this subset
        base = fit_any(nominal, obs, cov, sigma, (), theta0, solver, covariance)
        th, se, res = base.theta.copy(), base.theta_stderr.copy(), base.residual.copy()
        S = list(f.sensors)
        th[S], se[S], res[:, S] = f.theta[S], f.theta_stderr[S], f.residual[:, S]
        # chi2 and dof both of the fitted sensors (as ``fit`` defines them), not the others' chi2 over these' dof
        return Fit(th, se, f.components, res, f.chi2, f.dof, f.sensors, f.corr_base, f.corr_with, f.extra_cov)
    th = np.zeros((nominal.n, 5))
    se = np.zeros((nominal.n, 5))
    res = np.full(obs.d.shape, np.nan)
    chi2, dof = 0.0, 0
    for i in range(nominal.n):
        f = fit(nominal, obs, cov, sigma, (), sensors=[i], theta0=theta0, solver=solver, covariance=covariance)
        th[i], se[i], res[:, i] = f.theta[i], f.theta_stderr[i], f.residual[:, i]
        chi2 += f.chi2
        dof += f.dof
    return Fit(th, se, (), res, chi2, dof, tuple(range(nominal.n)))


def dof_per_sensor(f: Fit, obs, n):
    """(n,) float: residual degrees of freedom per sensor of ``f`` (readings less the five
    geometry parameters and each component's share)."""
    cnt = np.isfinite(obs.d).sum(axis=0).astype(float)
    dof = cnt - 5
    for c in f.components:
        if c.sensors:
            for i in c.sensors:
                dof[i] -= c.n_params / len(c.sensors)
        else:
            dof -= (c.n_params - (c.gauge_dof if c.per_pose else len(c.constraint(c.values)[0]))) / n
    return dof


def judged_residuals(f: Fit, obs, cov, sigma):
    """``(r (p, n) mm, dof (n,))``: the residuals of ``f`` as the noise battery judges them, and
    their degrees of freedom per sensor.

    Under a rigid pose error (several values a pose) those values take most of each pose's
    readings, unevenly over the sensors: each residual is then scaled by its own leverage, so
    every sensor's is N(0, sigma^2) again (readings of leverage near 1 are left out)."""
    rigid = [c for c in f.components if c.per_pose and c.per_pose_columns > 1]
    if not rigid:
        return f.residual, dof_per_sensor(f, obs, obs.d.shape[1])
    B = rigid[0].pose_columns(cov) / sigma[None, :, None]
    B = np.where(np.isfinite(obs.d)[..., None], B, 0.0)
    h = np.einsum("pnm,pmn->pn", B, np.linalg.pinv(B, rcond=1e-10))
    r = f.residual / np.sqrt(np.clip(1.0 - h, 1e-6, None))
    r = np.where(1.0 - h > 1e-3, r, np.nan)
    return r, np.isfinite(r).sum(axis=0) - 5.0


def residual_battery(f: Fit, obs, cov, sigma, names) -> NoiseTests:
    """The noise-model battery on ``f``'s residuals as the verdict judges them
    (:func:`judged_residuals`; the within-pose pairs tested unless a component is per pose):
    one place for the verdict and for the choice of a family's member."""
    r, dof = judged_residuals(f, obs, cov, sigma)
    return noise_tests(r, sigma, dof, names, pairs=not any(c.per_pose for c in f.components), rng=battery_rng())

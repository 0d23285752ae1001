"""The extended fit: the base model plus effect components, by least squares.

:func:`fit` poses the problem to the calibration's one least-squares engine
(:class:`~metrology.calibration.engine.LeastSquares`), solves it with ``scipy.optimize.least_squares``
or Gauss-Newton (:func:`~metrology.calibration.engine.gauss_newton`, the same minimum, faster
inside the k-fold loops) and reads its :class:`Fit`; :func:`fit_any` fits the sensors separately
when no component couples them.

No fit computed twice: the results of the diagnosis' fits are kept by the content of their inputs.

A diagnosis fits the same model to the same poses many times over: every one-sensor candidate's
k-fold refits the other sensors' base model on each fold, and a selection scores a candidate
again given the same causes. :func:`memoised` keeps a function's results in a bounded store
keyed by a digest of everything the result depends on
(:func:`~metrology.calibration.kept.content_key`: the bytes and shape
of every array, the class and fields of every dataclass, the ``repr`` of every other value), so
a hit returns what the call would have computed. The arrays of a kept result are made read-only:
a caller that wrote into a shared result would raise instead of changing another's.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from dataclasses import dataclass, field

import numpy as np

from metrology.calibration.engine import LeastSquares, clear_held, gauss_newton, geometry
from metrology.calibration.kept import Kept, content_key
from metrology.core.effects import Covariates, ExtendedModel
from metrology.core.layout import SensorLayout
from metrology.core.model import PARAMS_TANGENT, direction_from_tangent
from metrology.core.observations import Observations
from metrology.diagnosis.stats import Battery, NoiseTests, battery_rng, noise_tests

__all__ = ["FitData", "FitOptions", "Fit", "fit", "fit_any", "with_base", "gauss_newton", "geometry", "dof_per_sensor", "judged_residuals",
           "residual_battery",
           "memoised", "freeze", "clear_all", "new_store", "MAX_KEPT"]


# -- no fit computed twice: results kept by the content of their inputs ------------------------
#: results kept per memoised function (least recently used dropped first)
MAX_KEPT = 4096

_STORES: list = []  # every memoised function's store (clear_all)


def new_store(size: int = MAX_KEPT) -> Kept:
    """An empty store of at most ``size`` kept results that :func:`clear_all` clears too."""
    store = Kept(size)
    _STORES.append(store)
    return store


def clear_all() -> None:
    """Forget every kept result (a benchmark timing one diagnosis as a fresh process runs it)."""
    for store in _STORES:
        store.clear()
    clear_held()


def freeze(v):
    """Make the arrays of ``v`` (a dataclass, tuple or array, nested) read-only; returns ``v``."""
    if isinstance(v, np.ndarray):
        v.flags.writeable = False
    elif dataclasses.is_dataclass(v) and not isinstance(v, type):
        for f in dataclasses.fields(v):
            freeze(getattr(v, f.name))
    elif isinstance(v, (tuple, list)):
        for a in v:
            freeze(a)
    return v


def memoised(fn):
    """Decorator: keep the results of ``fn`` by the content of every argument it is called with
    (bound to its signature, defaults applied, passed to :func:`~metrology.calibration.kept.content_key`), at most
    :data:`MAX_KEPT` of them. An argument given as a list where an array was given before is a
    different key (a miss, never a wrong hit)."""
    sig = inspect.signature(fn)
    store = new_store()

    @functools.wraps(fn)
    def inner(*args, **kwargs):
        bound = sig.bind(*args, **kwargs)
        bound.apply_defaults()
        return store.get(content_key(tuple(bound.arguments.values())), lambda: freeze(fn(*args, **kwargs)))

    inner.cache_clear = store.clear
    inner.uncached = fn
    return inner


# -- the fit ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FitData:
    """What every fit of the diagnosis is posed on, held once: ``nominal`` the SensorLayout (the
    chart's centre), ``obs`` the Observations, ``cov`` the Covariates (same poses as ``obs``),
    ``sigma (n,) float, mm`` the reading noise used as weights."""

    nominal: SensorLayout
    obs: Observations
    cov: Covariates
    sigma: np.ndarray


@dataclass(frozen=True)
class FitOptions:
    """How :func:`fit` solves: ``loss`` ``"linear"`` or ``"soft_l1"`` (robust, scale 1 sigma);
    ``solver`` ``"lsq"`` (``scipy.optimize.least_squares``, trf) or ``"gn"`` (Gauss-Newton on the
    same residual and Jacobian with step halving: the same minimum, several times faster; used
    inside the k-fold loops); ``covariance`` compute the standard errors, correlations and
    ``extra_cov`` (False: a fit whose residuals and values alone are wanted, as the k-fold's;
    those are then zero, empty or None)."""

    loss: str = "linear"
    solver: str = "lsq"
    covariance: bool = True


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



@memoised
def fit(data: FitData, components=(), sensors=None, theta0=None, options: FitOptions = FitOptions()) -> Fit:
    """Least squares of the base model plus ``components`` (analytic Jacobian).

    Parameters
    ----------
    data : FitData, the layout, observations, covariates and reading noise
    components : sequence of Component (values are the starting point)
    sensors : sequence of int or None, the sensors whose base parameters are free and whose
        readings are fitted (default: every sensor if a component is of the set-up, else the
        components' sensors, else all)
    theta0 : (n, 5) float or None, start (and the fixed values of the other sensors)
    options : FitOptions, the loss, the solver and whether the covariance is computed

    A per-pose component (:class:`~metrology.core.effects.PoseError`) is profiled out exactly:
    its basis does not depend on the parameters, so for any base parameters the optimal
    per-pose values are a fixed linear map of the residual (variable projection); its values
    are then recovered with standard errors ``s / ||b_p||`` (reading noise only).

    Results are kept by the content of the inputs (:func:`memoised`): the same
    fit asked for again is not computed again, and its arrays are read-only.
    """
    p = LeastSquares(data.nominal, data.obs, data.sigma, components, sensors, theta0, data.cov)
    x = p.solve(options.solver, options.loss)
    return _fit_result(p, x, options.covariance)


def _fit_result(p: LeastSquares, x, covariance=True) -> Fit:
    """The :class:`Fit` of the problem ``p`` at its solution ``x``."""
    obs, S, ok, sig, n = p.obs, p.S, p.ok, p.sig, p.nominal.n
    R, e = p.residual_matrix(x)
    th, vals, _, f, _ = p.predict(x)
    res = np.full(obs.d.shape, np.nan)
    res[:, S] = np.where(ok, R * sig, np.nan)
    others = np.setdiff1d(np.arange(n), S)
    res[:, others] = obs.d[:, others] - p.d_full0[:, others] - f[:, others]
    dof = p.dof(x)
    chi2 = float(np.sum(R[ok] ** 2))
    if not covariance:
        it_free = iter(vals)
        out = [c.with_values(e.ravel()) if c.per_pose else c.with_values(next(it_free)) for c in p.comps]
        return Fit(th, np.zeros((n, 5)), tuple(out), res, chi2, dof, tuple(int(i) for i in S))
    s2 = chi2 / max(dof, 1)
    C = p.covariance(x, s2)
    se = np.sqrt(np.maximum(np.diag(C), 0.0))
    theta_se = np.zeros((n, 5))
    if not p.hold:
        theta_se[S] = se[:p.nb].reshape(-1, 5)
    out, corr_b, corr_w = _components_with_stderr(p, vals, e, s2, C, se)
    return Fit(th, theta_se, tuple(out), res, chi2, dof, tuple(int(i) for i in S), np.array(corr_b), tuple(corr_w),
               C[p.nb:, p.nb:])


def _components_with_stderr(p: LeastSquares, vals, e, s2, C, se):
    """The components with their values and standard errors, and per parameter of those fitted
    by value its largest |correlation| with a base parameter and that parameter's name."""
    nb, j = p.nb, p.nb
    out, corr_b, corr_w = [], [], []
    base_names = [f"{p.nominal.names[i]}.{q}" for i in p.S for q in PARAMS_TANGENT]
    it_free = iter(zip(p.free, vals))
    for c in p.comps:
        if c.per_pose:
            var = p.per_pose_variance()  # (p, m)
            out.append(c.with_values(e.ravel(), np.sqrt(s2 * np.maximum(var, 0.0)).ravel()))
            continue
        c2, v = next(it_free)
        kk = c2.n_params
        out.append(c2.with_values(v, se[j:j + kk]))
        for q in range(kk):
            if p.hold:  # the base parameters are held: no correlation with them
                corr_b.append(0.0)
                corr_w.append("held")
                continue
            cc = C[j + q, :nb] / np.maximum(se[j + q] * se[:nb], 1e-300)
            a = int(np.argmax(np.abs(cc)))
            corr_b.append(float(np.abs(cc[a])))
            corr_w.append(base_names[a])
        j += kk
    return out, corr_b, corr_w


def fit_any(data: FitData, comps, theta0, solver="gn", covariance=True) -> Fit:
    """:func:`fit`, with the sensors fitted separately when no component couples them (faster,
    identical); ``solver`` and ``covariance`` as :class:`FitOptions`'."""
    nominal, obs = data.nominal, data.obs
    options = FitOptions(solver=solver, covariance=covariance)
    if comps:
        f = fit(data, comps, theta0=theta0, options=options)
        return with_base(f, data, theta0, solver, covariance)
    th = np.zeros((nominal.n, 5))
    se = np.zeros((nominal.n, 5))
    res = np.full(obs.d.shape, np.nan)
    chi2, dof = 0.0, 0
    for i in range(nominal.n):
        f = fit(data, (), sensors=[i], theta0=theta0, options=options)
        th[i], se[i], res[:, i] = f.theta[i], f.theta_stderr[i], f.residual[:, i]
        chi2 += f.chi2
        dof += f.dof
    return Fit(th, se, (), res, chi2, dof, tuple(range(nominal.n)))


def with_base(f: Fit, data: FitData, theta0, solver="gn", covariance=True) -> Fit:
    """The fit ``f`` of some sensors with the other sensors' base fit (:func:`fit_any`'s)."""
    if len(f.sensors) == data.nominal.n:
        return f
    # the other sensors keep the base fit of this subset
    base = fit_any(data, (), theta0, solver, covariance)
    th, se, res = base.theta.copy(), base.theta_stderr.copy(), base.residual.copy()
    S = list(f.sensors)
    th[S], se[S], res[:, S] = f.theta[S], f.theta_stderr[S], f.residual[:, S]
    # chi2 and dof both of the fitted sensors (as ``fit`` defines them), not the others' chi2 over these' dof
    return Fit(th, se, f.components, res, f.chi2, f.dof, f.sensors, f.corr_base, f.corr_with, f.extra_cov)


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
    return noise_tests(r, sigma, dof, names, rng=battery_rng(), battery=Battery(pairs=not any(c.per_pose for c in f.components)))

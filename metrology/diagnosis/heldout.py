"""k-fold-by-pose held-out evaluation: every residual a prediction."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from metrology.core.effects import Outliers
from metrology.core.model import readings
from metrology.calibration.dataset import Dataset
from metrology.calibration.engine import LeastSquares
from metrology.calibration.kept import content_key
from metrology.diagnosis.fit import Fit, FitData, _fit_result, fit_any, freeze, geometry, memoised, new_store, with_base
from metrology.diagnosis.foldfit import FoldBatch

__all__ = ["folds", "heldout_eval", "HeldOut", "kfold", "beyond_span", "Problem"]


def folds(p, k):
    """Interleaved folds by pose (pose j in fold j mod k): each fold spans the whole run."""
    return [np.arange(j, p, k) for j in range(k)]


def beyond_span(d, k):
    """``(p, n)`` bool: the readings ``d (p, n)`` mm that, held out in their fold, lie outside
    the span of their sensor's readings in the other folds (a prediction there extrapolates a
    characteristic beyond what its fit saw)."""
    out = np.zeros(d.shape, bool)
    for test in folds(d.shape[0], k):
        train = np.setdiff1d(np.arange(d.shape[0]), test)
        lo, hi = np.nanmin(d[train], axis=0), np.nanmax(d[train], axis=0)
        with np.errstate(invalid="ignore"):
            out[test] = (d[test] < lo) | (d[test] > hi)
    return out


def heldout_eval(data: FitData, f: Fit, test, exclude=None):
    """Residuals (h, n) mm and normals of a fit on the held-out poses ``test`` of ``data``.

    A per-pose component's value of a held-out pose is fitted, for each reading, to the other
    sensors of that pose (leave one sensor out), so every residual is a prediction. A reading
    flagged as gross (``exclude (h, n)`` bool, the held-out poses' flags) predicts nothing: it
    is left out of that solve, and its own residual is NaN. Returns (residual (h, n) mm, normal
    deviation (h,) rad).
    """
    from metrology.core.normals import angle_between, micro_plane_normal

    nominal, obs, cov, sigma = data.nominal, data.obs, data.cov, data.sigma
    o, c = obs.select(test), cov.select(test)
    zero, u = geometry(nominal, f.theta)
    d0, _ = readings(zero, u, o.normal, o.offset)
    terms = np.zeros_like(d0)
    per_pose = []
    for comp in f.components:
        if comp.per_pose:
            per_pose.append((replace(comp, n_poses=len(test), values=None, stderr=None), comp))
        elif isinstance(comp, Outliers):
            continue  # flagged held-out readings are left out of the figures
        else:
            terms += comp.evaluate(comp.values, d0, c)
    res = o.d - d0 - terms
    if exclude is not None:
        res = np.where(exclude, np.nan, res)
    for comp, fitted in per_pose:
        # a per-pose value is not known before the pose is measured: each reading is predicted
        # with the value fitted to the *other* sensors of its pose (leave one sensor out), so
        # the held-out residual is a true prediction and nothing is charged as lost dof
        B = comp.pose_columns(c)  # (h, n, m)
        m = B.shape[2]
        fin = np.isfinite(res)
        w = np.where(fin[..., None], B / sigma[None, :, None], 0.0)  # (h, n, m)
        r = np.where(fin, res / sigma[None, :], 0.0)  # (h, n)
        # with several values a pose (offset and tilts), the other sensors of a pose determine
        # them exactly or nearly so, and the prediction of the left-out reading extrapolates
        # their noise: the values are shrunk towards zero by their spread over the training
        # poses (the best linear unbiased predictor of a random per-pose error)
        prior = None if m == 1 else _per_pose_precision(fitted, nominal, cov, sigma, test)
        n = res.shape[1]
        # every sensor left out at once, and last every reading (for the normal): (n + 1, h, n, m)
        wi = np.repeat(w[None], n + 1, axis=0)
        wi[np.arange(n), :, np.arange(n), :] = 0.0  # stack i without reading i
        e = _solve_per_pose(wi, np.broadcast_to(r, wi.shape[:3]), prior)  # (n + 1, h, m)
        pred = np.einsum("hnm,nhm->hn", B, e[:n])
        e_all = e[n]
        res = res - pred
        terms = terms + np.einsum("hnm,hm->hn", B, e_all)
    dc = o.d - terms
    nrm = micro_plane_normal(zero, u, dc)
    dev = angle_between(nrm, o.normal)
    return res, dev


def _solve_per_pose(w, r, prior=None):
    """Per pose, the values ``e (..., h, m)`` minimising ``|r - w e|^2 + e^T P e`` (``w (..., h,
    n, m)``, ``r (..., h, n)``; ``P`` the prior precision (m, m), or none: the minimum-norm least
    squares)."""
    if prior is None:
        return (np.linalg.pinv(w, rcond=1e-10) @ r[..., None])[..., 0]
    A = np.einsum("...nm,...nq->...mq", w, w) + prior
    b = np.einsum("...nm,...n->...m", w, r)
    # minimum norm where a pose's other readings and a weak prior leave a value undetermined
    # (a blank reading beside the left-out one; per-pose values of no spread-limited size)
    return (np.linalg.pinv(A, rcond=1e-12, hermitian=True) @ b[..., None])[..., 0]


def _per_pose_precision(fitted, nominal, cov, sigma, test):
    """Inverse of the spread of the per-pose values over the training poses, less what reading
    noise puts in them (``(m, m)``; a large number where they show none)."""
    m = fitted.per_pose_columns
    e = np.asarray(fitted.values, float).reshape(-1, m)
    S = np.cov(e, rowvar=False) - _pose_noise(replace(fitted, values=None, stderr=None), cov, sigma, test)
    vals, vecs = np.linalg.eigh(0.5 * (S + S.T))
    vals = np.maximum(vals, 1e-12 * max(float(np.max(np.abs(vals))), 1e-300))
    return (vecs / vals) @ vecs.T


@memoised
def _pose_noise(columns, cov, sigma, test):
    """``(m, m)``: what reading noise puts in the per-pose values of ``columns`` (a per-pose
    component, its values aside), averaged over the training poses (all but ``test``); the same
    for every model with that component on that fold (kept)."""
    train = np.setdiff1d(np.arange(cov.n_poses), test)
    B = columns.pose_columns(cov.select(train)) / sigma[None, :, None]
    return np.mean(np.linalg.pinv(np.einsum("hnm,hnq->hmq", B, B), hermitian=True), axis=0)


@dataclass(frozen=True)
class HeldOut:
    """k-fold held-out figures of one model.

    Attributes
    ----------
    residual : (p, n) float, mm, held-out residuals (predictions: see :func:`heldout_eval`)
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


@memoised
def kfold(data: FitData, components, k, theta0):
    """k-fold-by-pose held-out figures of the base model plus ``components`` (kept by the
    content of the inputs: the same figures asked for again are not computed again)."""
    nominal, obs, cov, sigma = data.nominal, data.obs, data.cov, data.sigma
    p = obs.n_poses
    res = np.full(obs.d.shape, np.nan)
    dev = np.full(p, np.nan)
    gross = [c.flags for c in components if isinstance(c, Outliers)]
    sets = _training_sets(obs, cov, k)
    for (test, _, _, _), f in zip(sets, _fold_fits(nominal, sigma, components, theta0, sets)):
        res[test], dev[test] = heldout_eval(data, f, test, gross[0][test] if gross else None)
    return HeldOut(res, dev)


def _fold_fits(nominal, sigma, components, theta0, sets):
    """Each fold's fit of the base model plus ``components`` (:func:`fit_any`'s, without the
    covariance); the folds of a fit of one sensor's components solved as one problem
    (:class:`~metrology.diagnosis.foldfit.FoldBatch`)."""
    comps = [[c.select(train) for c in components] for _, train, _, _ in sets]
    one = {c.sensors for c in components}
    if components and len(one) == 1 and len(next(iter(one))) == 1 and not any(c.per_pose for c in components):
        problems = [LeastSquares(nominal, obs_t, sigma, cs, None, theta0, cov_t)
                    for cs, (_, _, obs_t, cov_t) in zip(comps, sets)]
        if FoldBatch.applies(problems):
            X = FoldBatch(problems).solve()
            return [with_base(_fit_result(p, x, covariance=False), FitData(nominal, p.obs, p.cov, sigma), theta0,
                              covariance=False) for p, x in zip(problems, X)]
    return [fit_any(FitData(nominal, obs_t, cov_t, sigma), cs, theta0, covariance=False)
            for cs, (_, _, obs_t, cov_t) in zip(comps, sets)]


_TRAINING = new_store(8)  # content key of (obs, cov, k) -> its folds' training sets (the last few data sets)


def _training_sets(obs, cov, k):
    """``[(test, train, obs of train, cov of train)]`` per fold: made once per data set, so the
    fits of every candidate on a fold see the same objects (their content keyed once)."""
    def make():
        p = obs.n_poses
        sets = []
        for test in folds(p, k):
            train = np.setdiff1d(np.arange(p), test)
            sets.append((test, train, obs.select(train), cov.select(train)))
        return freeze(sets)

    return _TRAINING.get(content_key(obs, cov, int(k)), make)


@dataclass(frozen=True)
class Problem:
    """The problem the selection and the verdict refit, held once (as lmfit's ``Minimizer`` holds
    its function and arguments): ``ds`` the Dataset, ``b`` the BaseAnalysis (the base model:
    its covariates, noise and calibration), ``folds`` the k of the k-fold by pose."""

    ds: Dataset
    b: "BaseAnalysis"  # metrology.diagnosis.decide's (which imports this module)
    folds: int

    @property
    def data(self) -> FitData:
        """What its fits are posed on: the layout, observations, covariates and reading noise."""
        ds, b = self.ds, self.b
        return FitData(ds.layout, ds.obs, b.cov, b.sigma)

    def fit(self, components, theta0, solver: str = "gn") -> Fit:
        """The base model plus ``components`` fitted from ``theta0`` (:func:`~metrology.diagnosis.fit.fit_any`)."""
        return fit_any(self.data, tuple(components), theta0, solver)

    def heldout(self, components, theta0) -> HeldOut:
        """Its k-fold-by-pose held-out figures (:func:`kfold`)."""
        return kfold(self.data, tuple(components), self.folds, theta0)

    def refit(self, components, theta0) -> tuple:
        """``(fit, held-out figures)`` of the base model plus ``components`` from ``theta0``."""
        return self.fit(components, theta0), self.heldout(components, theta0)

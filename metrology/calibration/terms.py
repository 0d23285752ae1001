"""The sensors and the head's effect terms estimated jointly: ``metro calibrate --layout extended.toml``
and ``metro diagnose --out``.

A layout with ``[sensors.effects.*]`` terms (:mod:`metrology.core.effects.terms`) is refitted
whole: the five chart parameters of every sensor and the terms' parameters, by the one
least-squares engine (:class:`~metrology.calibration.engine.LeastSquares`, the base model plus
registry components), the terms' values in the layout the starting point. The covariates (each
beam's incidence on the datum, the temperature) are those of the poses at the base calibration
(held fixed, as in the diagnosis' extended fits). Standard errors are scaled by the residual
(``m - p`` degrees of freedom), as the base ``lsq``'s.

**Which terms the poses identify.** A term whose covariate does not move over the poses (a
temperature coefficient calibrated at one temperature: the column is zero) or that the base
parameters take whole (variance inflation above :data:`TERM_VIF_MAX`) is not re-estimated: it is
carried with the value and covariance the layout gave (a prior, uncorrelated with this fit), and
the report says so. The filters ``ekf`` and ``iekf`` carry the terms in their state
(:mod:`metrology.calibration.terms_filter`); ``ekf_paper`` and ``method1`` refuse an extended
layout (:func:`check_method`). :func:`metrology.calibration.terms_filter.calibrate_terms`
runs the one chosen.

With a datum covariance (a scanned cloud) the datum plane is then estimated with the sensors as in
the base calibration (:func:`metrology.calibration.calibrate.with_datum`), on the readings with the
fitted terms removed; the terms' covariance is the joint fit's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TermFit", "fit_with_terms", "check_method", "dataset_covariates", "corrected_obs",
           "TERM_VIF_MAX", "identify_terms", "carried_cov", "FILTER_METHODS"]

#: the filters whose state carries a layout's terms (:mod:`metrology.calibration.terms_filter`;
#: ``ekf_paper`` is the paper's as printed: its six raw errors only)
FILTER_METHODS = ("ekf", "iekf")

#: a term parameter whose variance the base parameters inflate beyond this (its standard error
#: more than 300x what it would be with the base known) is not identified by the poses: the data
#: cannot tell it from the zero point and beam (a gain on a run at one stand-off). A gain over
#: the 40 mm stand-off spread of a drawn calibration run (metrology.sim.forward.draw_calibration)
#: has about 2e3: the zero along its beam takes its mean, the spread separates the rest
TERM_VIF_MAX = 1e5


def check_method(layout, method: str) -> None:
    """Refuse an estimator that cannot apply the layout's terms (one line): ``lsq`` and the filters
    ``ekf``, ``iekf`` (:mod:`metrology.calibration.terms_filter`) carry them."""
    if layout.effects is not None and method != "lsq" and method not in FILTER_METHODS:
        labels = ", ".join(c.label for c in layout.effects.components)
        raise ValueError(f"method {method}: the layout has effect terms ({labels}) that {method} cannot estimate "
                         f"(its state is the paper's six raw errors); use --method lsq, ekf or iekf, or a layout "
                         f"without [sensors.effects]")


@dataclass(frozen=True)
class TermFit:
    """What the joint fit says of each term.

    terms : HeadTerms, the fitted terms with the joint covariance; identified : tuple of bool, per
    component; why : tuple of str, per component (empty when identified); vif : tuple of float, the
    largest variance inflation of each component's parameters
    """

    terms: object
    identified: tuple
    why: tuple
    vif: tuple

    def to_dict(self) -> list:
        out = []
        for d, ok, why, v in zip(self.terms.describe(), self.identified, self.why, self.vif):
            out.append({**d, "identified": bool(ok), "why_not": why or None,
                        "vif": None if not np.isfinite(v) else float(v)})
        return out


def dataset_covariates(layout, obs, export, plane, datum_points=None):
    """The :class:`~metrology.core.effects.Covariates` of the poses of a calibration run for
    ``layout``'s sensors (incidence on the datum, temperature; the spot positions about the datum's
    centre, its inlier points' mean where given)."""
    from metrology.core.effects import Covariates

    centre = (np.mean(datum_points, axis=0) if datum_points is not None and len(datum_points)
              else -plane.offset * plane.normal)
    return Covariates.from_geometry(layout.zero, layout.direction, obs.normal, obs.offset, export.tcs2tracker_rot,
                                    export.tcs2tracker_trans, plane.normal, centre, layout.range_mm,
                                    time_s=export.time_s, temp_c=export.temp_c)


def _recentre(u0, ab):
    """``(5n, 5n)``: the chart's change from around ``u0`` to around the fitted directions (as
    :func:`metrology.core.model.chart_cov_recentred`, whose ``T`` this is)."""
    from scipy.linalg import block_diag

    from metrology.core.model import direction_basis

    u0 = np.asarray(u0, float) / np.linalg.norm(u0, axis=1, keepdims=True)
    E = direction_basis(u0)
    w = u0 + np.einsum("nk,nkj->nj", ab, E)
    wn = np.linalg.norm(w, axis=1)
    u = w / wn[:, None]
    proj = (np.eye(3)[None] - u[:, :, None] * u[:, None, :]) / wn[:, None, None]
    T2 = np.einsum("nkj,nji,nli->nkl", direction_basis(u), proj, E)
    T = np.zeros((len(u0), 5, 5))
    T[:, :3, :3] = np.eye(3)
    T[:, 3:, 3:] = T2
    return block_diag(*T)


def identify_terms(nominal, obs, cov, comps, sigma, theta0):
    """Which of ``comps`` the poses identify: ``(held, why, vif)``, per component: held (bool) when its
    covariate does not move over the poses (a zero column) or the base parameters take it (variance
    inflation above :data:`TERM_VIF_MAX`), why in words (empty when identified), its largest variance
    inflation. ``sigma (n,) mm`` the readings' weights, ``theta0 (n, 5)`` where the Jacobian is taken."""
    from metrology.calibration.engine import LeastSquares

    n = nominal.n
    probe = LeastSquares(nominal, obs, sigma, comps, sensors=range(n), theta0=theta0, cov=cov)
    J = probe.jacobian(probe.x0)
    nb = 5 * n
    held, why, vif_of = [], [], []
    off = nb
    base = J[:, :nb]
    for c in comps:
        cols = J[:, off:off + c.n_params]
        off += c.n_params
        norm = np.linalg.norm(cols, axis=0)
        if np.any(norm == 0):
            held.append(True)
            why.append("its covariate does not change over these poses (e.g. one temperature): carried from "
                       "the layout, not re-estimated")
            vif_of.append(np.inf)
            continue
        A = np.concatenate([base, cols], axis=1)
        s = np.linalg.norm(A, axis=0)
        s = np.where(s > 0, s, 1.0)
        inv = np.linalg.pinv((A / s).T @ (A / s), hermitian=True)
        v = float(np.max(np.diag(inv)[nb:]))
        vif_of.append(v)
        held.append(v > TERM_VIF_MAX)
        why.append(f"the zero points and beams take it (variance inflation {v:.3g} > {TERM_VIF_MAX:g}): carried "
                   f"from the layout, not re-estimated" if v > TERM_VIF_MAX else "")
    return held, why, vif_of


def fit_with_terms(nominal, obs, cov, components, sigma=None, prior=None, theta0=None):
    """Fit the sensors of ``nominal`` and ``components`` (registry components on single sensors,
    their values the start) jointly to ``obs`` (:class:`~metrology.core.Observations`, covariates
    ``cov``). ``prior`` the layout's :class:`HeadTerms` (their covariance carried for a term the
    poses do not identify), or None. Returns ``(theta (n, 5), cov_full (5n + k, 5n + k) in the
    nominal chart, sigma (n,) mm, TermFit)``; the TermFit's terms are in the chart of the fitted
    directions."""
    from metrology.calibration.engine import LeastSquares
    from metrology.core.effects.terms import HeadTerms

    n = nominal.n
    comps = tuple(components)
    theta0 = np.zeros((n, 5)) if theta0 is None else theta0
    w = np.ones(n) if sigma is None else np.asarray(sigma, float)
    held, why, vif_of = identify_terms(nominal, obs, cov, comps, w, theta0)
    nb = 5 * n
    free = [c for c, h in zip(comps, held) if not h]
    fixed = [c for c, h in zip(comps, held) if h]
    if fixed:  # held terms removed from the readings at their layout values
        kf = sum(c.n_params for c in fixed)
        obs = corrected_obs(HeadTerms(tuple(fixed), np.zeros((kf, kf)), np.zeros((nb, kf))), obs, cov)
    p = LeastSquares(nominal, obs, w, tuple(free), sensors=range(n), theta0=theta0, cov=cov)
    x = p.solve("lsq", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    r = p.residual(x)
    m = int(np.sum(p.ok))
    k = len(x)
    s2 = float(np.sum(r ** 2) / max(m - k, 1))
    C = p.covariance(x, s2, J=p.result.jac)
    theta, vals = p.unpack(x)
    # per sensor residual RMS (mm) in the weights' units
    R, _ = p.residual_matrix(x)
    sig = np.sqrt(np.sum(R ** 2, axis=0) / np.maximum(p.ok.sum(0) - 5, 1)) * p.sig
    fitted, it = [], iter(vals)
    kt = sum(c.n_params for c in comps)
    C_full = np.zeros((nb + kt, nb + kt))
    C_full[:nb, :nb] = C[:nb, :nb]
    pos_free, o = [], nb
    src = {}  # component index -> its columns in C
    j = nb
    for c in free:
        src[id(c)] = list(range(j, j + c.n_params))
        j += c.n_params
    for c, h in zip(comps, held):
        cols = list(range(o, o + c.n_params))
        if h:  # carried: the layout's covariance, else (a term no layout gave) its physical range as 1 sigma
            C_full[np.ix_(cols, cols)] = carried_cov(prior, c)
            fitted.append(c.with_values(c.values, np.sqrt(np.diag(C_full[np.ix_(cols, cols)]))))
        else:
            v = next(it)
            sc = src[id(c)]
            fitted.append(c.with_values(v, np.sqrt(np.maximum(np.diag(C)[sc], 0.0))))
            pos_free.append((cols, sc))
        o += c.n_params
    for cols, sc in pos_free:
        C_full[np.ix_(cols, list(range(nb)))] = C[np.ix_(sc, list(range(nb)))]
        C_full[np.ix_(list(range(nb)), cols)] = C[np.ix_(list(range(nb)), sc)]
        for cols2, sc2 in pos_free:
            C_full[np.ix_(cols, cols2)] = C[np.ix_(sc, sc2)]
    T = _recentre(nominal.direction, theta[:, 3:])
    cross = T @ C_full[:nb, nb:]
    terms = HeadTerms(tuple(fitted), C_full[nb:, nb:], cross)
    fit = TermFit(terms, tuple(not h for h in held), tuple(why), tuple(vif_of))
    return theta, C_full, sig, fit


def carried_cov(prior, comp):
    """``(k, k)``: the covariance a term carries from the layout ``prior`` (HeadTerms or None); a term no
    layout gave, its physical range (:data:`~metrology.core.effects.terms.TERM_LIMITS`) as 1 sigma."""
    pi = _prior_index(prior, comp)
    if pi is not None:
        return prior.cov[np.ix_(pi, pi)]
    from metrology.core.effects.terms import SPLINE_LIMIT_MM, TERM_LIMITS

    se = np.array([TERM_LIMITS.get(pn, SPLINE_LIMIT_MM) for pn in comp.param_names])
    return np.diag(se ** 2)


def _prior_index(prior, comp):
    """The columns of ``comp``'s parameters in ``prior`` (HeadTerms), or None."""
    if prior is None:
        return None
    names = prior.param_names
    try:
        return [names.index(p) for p in comp.full_param_names]
    except ValueError:
        return None


def corrected_obs(terms, obs, cov):
    """``obs`` with ``terms`` removed from its readings (the covariates ``cov`` of its poses)."""
    from metrology.core.effects.apply import correct_readings
    from metrology.core.observations import Observations

    return Observations(obs.normal, obs.offset, correct_readings(terms, obs.d, cov, "the export").d)

"""The filters with their state extended by a layout's head terms: ``metro calibrate --layout
extended.toml --method ekf`` (or ``iekf``).

The state of each sensor's filter (filterpy's ``ExtendedKalmanFilter``, one filter per sensor as
:func:`metrology.calibration.kalman.ekf`) is its five chart parameters ``(x, y, z, a, b)``
followed by the parameters of the terms acting on it (each term is on one sensor, so the sensors'
filters stay independent). The measurement function is the extended model,
``h(x) = d0(x) + sum_c B_c(d0, covariates) v_c`` (every catalogued term is linear in its values,
:mod:`metrology.core.effects`), its Jacobian ``[g dd0/dchart, B_c]`` with ``g = 1 + sum_c df_c/dd0``,
as the least-squares engine's (:class:`~metrology.calibration.engine.LeastSquares`).

The prior: the chart's as the base filters' (:data:`~metrology.calibration.kalman.DEFAULT_P0_SIGMA`,
mean zero), the terms' mean their values in the layout and their covariance the layout's stated
one (``[calibration]``: the terms' block; the layout's cross covariance of the terms with a chart
fitted before is not carried, that chart is not this one's centre). The first pass is linearised at
the base least-squares chart and the terms' layout values (:data:`LINEARISE`); ``iekf`` runs more
passes, each linearised at the previous pass's estimate (the MAP estimate with that prior, in filter form).

Which terms the poses identify is decided as on the least-squares path
(:func:`metrology.calibration.terms.identify_terms`); a term they do not identify is removed from
the readings at its layout value and carried with the layout's covariance. The covariance the
filter states is ``P`` (the stated noise ``noise_mm`` and the prior), not residual-scaled.

:func:`calibrate_terms` runs the method chosen (least squares or a filter) on a dataset.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.calibration.terms import FILTER_METHODS

__all__ = ["filter_with_terms", "calibrate_terms", "LINEARISE"]

#: where the filters' first pass is linearised. ``"base"``: at the base least-squares chart the joint fit
#: starts from (the layout's sensors calibrated without terms, which judges identifiability) and the terms'
#: layout values; the prior stays the chart's ``N(0, P0)`` and the terms'. Measured on six forward-simulated
#: heads (gain -0.8 %, 3 um/K; seeds 5-10): the one-pass EKF's terms 0.03-0.27 sigma from least squares'
#: (at the running estimate from the nominal, ``"running"``: 0.15-2.41 sigma, its Jacobians those of its
#: first, wrong estimates), the IEKF's unchanged (the MAP estimate either way)
LINEARISE = ("base", "running")


def _h_and_H(nominal, i, comps, x, N, D, cov):
    """Sensor ``i``'s extended model at the state ``x (5 + k,)`` on the poses of ``N (m, 3)``, ``D (m,)``,
    ``cov`` (their Covariates): ``(h (m,) mm, H (m, 5 + k))``; a beam that misses the datum gives NaN."""
    from metrology.core.model import direction_from_tangent, jacobian_tangent, readings

    u0 = nominal.direction[i][None]
    E = nominal.zero[i][None] + x[:3]
    d = readings(E, direction_from_tangent(u0, x[None, 3:5]), N, D)[0][:, 0]
    J = jacobian_tangent(E, u0, x[None, 3:5], N, D)[:, 0, :]
    d0 = np.zeros((len(d), nominal.n))
    d0[:, i] = d
    f, g, cols, off = np.zeros(len(d)), np.ones(len(d)), [], 5
    for c in comps:
        v = x[off:off + c.n_params]
        off += c.n_params
        B = c.basis(d0, cov)[:, i, :]
        f += B @ v
        if c.uses_d0:
            g += c.d_dd0(v, d0, cov)[:, i]
        cols.append(B)
    return d + f, np.concatenate([J * g[:, None]] + cols, axis=1)


def _pass(nominal, i, comps, obs, cov, rows, R, m0, P0, x_ref=None, Q=0.0):
    """One filterpy EKF pass over sensor ``i``'s readings ``rows`` from the prior ``N(m0, P0)``; linearised
    at the running estimate (``x_ref`` None) or at every measurement at ``x_ref``; ``Q`` the process noise
    on every state (as :func:`metrology.calibration.kalman.ekf`'s)."""
    from filterpy.kalman import ExtendedKalmanFilter

    k = len(m0)
    kf = ExtendedKalmanFilter(dim_x=k, dim_z=1)
    kf.x = m0[:, None].copy()
    kf.P = P0.copy()
    kf.Q = Q * np.eye(k)
    kf.R = np.array([[R]])
    if x_ref is not None:
        h_ref, H_ref = _h_and_H(nominal, i, comps, x_ref, obs.normal[rows], obs.offset[rows], cov.select(rows))
    for j, p in enumerate(rows):
        if x_ref is None:
            h, H = _h_and_H(nominal, i, comps, kf.x[:, 0], obs.normal[p:p + 1], obs.offset[p:p + 1],
                            cov.select([p]))
            Hx = lambda x, h=h: np.array([[h[0]]])  # noqa: E731  (filterpy asks at the prior's x)
        else:
            h, H = h_ref[j:j + 1], H_ref[j:j + 1]
            Hx = lambda x, h=h, H=H: np.array([[h[0]]]) + H @ (x - x_ref[:, None])  # noqa: E731
        if not (np.isfinite(h[0]) and np.all(np.isfinite(H))):
            continue  # the beam misses the datum at this estimate: the reading tells nothing
        kf.predict()
        kf.update(np.array([[obs.d[p, i]]]), lambda x, H=H: H, Hx)
    return kf.x[:, 0].copy(), 0.5 * (kf.P + kf.P.T)


def _residual_cov(nominal, i, comps, obs, cov, rows, x):
    """Sensor ``i``'s scatter (mm) and residual-scaled covariance over its chart and terms at the state ``x``."""
    from metrology.calibration.uncertainty import residual_scaled_cov

    h, H = _h_and_H(nominal, i, comps, x, obs.normal[rows], obs.offset[rows], cov.select(rows))
    ok = np.isfinite(h) & np.all(np.isfinite(H), axis=1)
    return residual_scaled_cov(H[ok], (obs.d[rows, i] - h)[ok])


def filter_with_terms(nominal, obs, cov, components, prior, method="ekf", sigma_mm=None, P0_sigma=None, Q=0.0,
                      passes=10, tol=(1e-6, 1e-8), stderr="stated", theta0=None, linearise="base"):
    """Fit the sensors of ``nominal`` and the layout's terms ``components`` by the filter ``method``
    (``ekf`` or ``iekf``) with the state extended by the terms.

    Parameters
    ----------
    nominal : SensorLayout, the chart's centre (its ``noise_mm`` the stated noise unless ``sigma_mm``)
    obs : Observations; cov : Covariates of its poses
    components : the layout's terms (each on one sensor, its values the prior's mean)
    prior : HeadTerms, the layout's terms with their covariance (the prior's covariance)
    P0_sigma : (float, float) or None, the chart's prior 1 sigma (mm, rad); None: the base filters'
    Q : float, ``ekf`` only, the process noise on every state, as :func:`metrology.calibration.kalman.ekf`
        (``iekf`` linearises each pass at the previous estimate with ``Q = 0``, as its base filter)
    passes, tol : ``iekf`` only, as :func:`metrology.calibration.kalman.iekf`
    stderr : ``"stated"`` (default) the filter's ``P``; ``"residual"`` what least squares reports,
        ``s^2 (J^T J)^-1`` over the sensor's chart and its fitted terms at the estimate, ``s`` the residuals'
        scatter (:func:`metrology.calibration.uncertainty.residual_scaled_cov`), returned as its sigma (as
        :func:`metrology.calibration.kalman.iekf`'s)
    theta0 : (n, 5) float or None, where identifiability is judged (the base calibration)
    linearise : ``"base"`` (default): the first pass linearised at ``theta0`` and the terms' layout values
        (:data:`LINEARISE`); ``"running"``: at the running estimate from the nominal, as the base
        :func:`metrology.calibration.kalman.ekf` (also where ``theta0`` is None)

    Returns
    -------
    ``(theta (n, 5), cov_full (5n + k, 5n + k) in the nominal chart, sigma (n,) mm, TermFit)`` as
    :func:`metrology.calibration.terms.fit_with_terms`
    """
    from metrology.calibration.fitted import _pose_order, _sigma
    from metrology.calibration.kalman import DEFAULT_P0_SIGMA, _prior
    from metrology.calibration.terms import TermFit, _recentre, carried_cov, corrected_obs, identify_terms
    from metrology.core.effects.terms import HeadTerms

    if method not in FILTER_METHODS:
        raise ValueError(f"method {method!r}: the filters whose state carries terms are {', '.join(FILTER_METHODS)}")
    if stderr not in ("stated", "residual"):
        raise ValueError(f"stderr {stderr!r}: expected 'stated' or 'residual'")
    if linearise not in LINEARISE:
        raise ValueError(f"linearise {linearise!r}: expected one of {', '.join(LINEARISE)}")
    if not (np.isfinite(Q) and Q >= 0):
        raise ValueError(f"Q must be a finite number >= 0, got {Q!r}")
    if method == "iekf" and Q != 0:
        raise ValueError(f"Q = {Q:g}: iekf takes no process noise (each pass the MAP estimate with Q = 0); use ekf")
    n, nb = nominal.n, 5 * nominal.n
    sigma = _sigma(nominal, sigma_mm)
    if not np.all(np.isfinite(sigma)):
        raise ValueError(f"{method} needs the reading noise: give noise_mm in the layout")
    comps = tuple(components)
    at_base = linearise == "base" and theta0 is not None
    theta0 = np.zeros((n, 5)) if theta0 is None else theta0
    held, why, vif = identify_terms(nominal, obs, cov, comps, sigma, theta0)
    fixed = [c for c, h in zip(comps, held) if h]
    if fixed:  # held terms removed from the readings at their layout values
        kf = sum(c.n_params for c in fixed)
        obs = corrected_obs(HeadTerms(tuple(fixed), np.zeros((kf, kf)), np.zeros((nb, kf))), obs, cov)
    P0_base = _prior(DEFAULT_P0_SIGMA if P0_sigma is None else P0_sigma)
    offs = np.cumsum([nb] + [c.n_params for c in comps])  # each component's first column in the full state
    kt = int(offs[-1] - nb)
    C_full = np.zeros((nb + kt, nb + kt))
    theta = np.zeros((n, 5))
    values = {}
    for i in range(n):
        mine = [j for j, c in enumerate(comps) if c.sensors[0] == i and not held[j]]
        m0 = np.concatenate([np.zeros(5)] + [np.asarray(comps[j].values, float) for j in mine])
        P0 = np.zeros((len(m0), len(m0)))
        P0[:5, :5] = P0_base
        o = 5
        for j in mine:
            k = comps[j].n_params
            P0[o:o + k, o:o + k] = carried_cov(prior, comps[j])
            o += k
        mc = [comps[j] for j in mine]
        rows = _pose_order(obs, i)
        start = np.concatenate([theta0[i], m0[5:]]) if at_base else None
        x, P = _pass(nominal, i, mc, obs, cov, rows, sigma[i] ** 2, m0, P0, x_ref=start, Q=Q)
        for _ in range(passes - 1 if method == "iekf" else 0):
            x_new, P = _pass(nominal, i, mc, obs, cov, rows, sigma[i] ** 2, m0, P0, x_ref=x)
            step, x = np.abs(x_new - x), x_new
            if np.all(step[:3] < tol[0]) and np.all(step[3:5] < tol[1]):
                break
        theta[i] = x[:5]
        if stderr == "residual":
            sigma[i], P = _residual_cov(nominal, i, mc, obs, cov, rows, x)
        idx = list(range(5 * i, 5 * i + 5))
        o = 5
        for j in mine:
            k = comps[j].n_params
            idx += list(range(offs[j], offs[j] + k))
            values[j] = x[o:o + k]
            o += k
        C_full[np.ix_(idx, idx)] = P
    fitted = []
    for j, c in enumerate(comps):
        cols = list(range(offs[j], offs[j] + c.n_params))
        if held[j]:
            C_full[np.ix_(cols, cols)] = carried_cov(prior, c)
        v = c.values if held[j] else values[j]
        fitted.append(c.with_values(v, np.sqrt(np.maximum(np.diag(C_full[np.ix_(cols, cols)]), 0.0))))
    cross = _recentre(nominal.direction, theta[:, 3:]) @ C_full[:nb, nb:]
    terms = HeadTerms(tuple(fitted), C_full[nb:, nb:], cross)
    return theta, C_full, sigma, TermFit(terms, tuple(not h for h in held), tuple(why), tuple(vif))


def calibrate_terms(dataset, method="lsq", **opts):
    """Calibrate ``dataset`` (its layout carries terms) jointly with its terms by ``method`` (``lsq``,
    or a filter with its state extended by the terms: ``ekf``, ``iekf``, ``opts`` theirs): ``(Calibration
    whose layout carries the fitted terms, TermFit, the observations with the terms removed)``; the
    datum's covariance is the caller's (:func:`metrology.calibration.calibrate.calibrate_dataset`)."""
    from metrology.calibration.estimators import calibrate
    from metrology.calibration.fitted import _finish
    from metrology.calibration.terms import corrected_obs, dataset_covariates, fit_with_terms
    from metrology.core.model import chart_cov_recentred

    prior = dataset.layout.effects
    nominal = replace(dataset.layout, effects=None)
    obs = dataset.obs
    cal0 = calibrate(nominal, obs, "lsq")
    cov = dataset_covariates(cal0.layout, obs, dataset.export, dataset.plane, dataset.datum_points)
    if method == "lsq":
        theta, C, sig, fit = fit_with_terms(nominal, obs, cov, prior.components, prior=prior, theta0=cal0.theta)
    else:
        theta, C, sig, fit = filter_with_terms(nominal, obs, cov, prior.components, prior, method,
                                               theta0=cal0.theta, **opts)
    n = nominal.n
    obs_c = corrected_obs(fit.terms, obs, cov)
    blocks = np.stack([C[5 * i:5 * i + 5, 5 * i:5 * i + 5] for i in range(n)])
    cal = _finish(method, nominal, obs_c, theta, blocks, sig)
    base = chart_cov_recentred(nominal.direction, theta[:, 3:], C[:5 * n, :5 * n])
    cal = replace(cal, layout=replace(cal.layout, covariance=0.5 * (base + base.T)))
    return replace(cal, layout=replace(cal.layout, effects=fit.terms)), fit, obs_c

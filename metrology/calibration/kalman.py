"""The sequential estimators of the sensor parameters: the paper's EKF (section 3.2) and the well-posed
filters on the five-parameter chart, each returning a :class:`~metrology.calibration.fitted.Calibration`.

``ekf_paper``
    Eqs. 10-16 as printed, with filterpy's ``ExtendedKalmanFilter``: state = the six raw
    errors (dx, dy, dz, dm, dn, dq) of one sensor, random walk with ``Q``, ``P0 = I`` (mixed
    units: 1 mm^2 and 1 (unit of direction)^2), linear innovation ``Z - H X`` (Eq. 16) with
    ``H`` evaluated at the current estimate, stop at ``||X_k - X_k-1|| < delta``.
``ekf``
    filterpy EKF on the five identifiable parameters (x, y, z, a, b) of metro's chart, a
    prior in consistent units (``P0 = diag((2 mm)^2 x3, (0.1 rad)^2 x2)`` by default), the
    full nonlinear measurement function ``h(x) = d(x)`` and ``R`` from the stated noise.
``iekf``
    The same filter run in passes, each linearised at the previous pass's estimate:
    Gauss-Newton on the MAP cost in filter form; converges to batch least squares with
    the prior.
"""

from __future__ import annotations

import numpy as np

from metrology.calibration.fitted import Calibration, _finish, _pose_order, _sigma
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, direction_from_tangent, jacobian_raw, jacobian_tangent, readings
from metrology.core.observations import Observations

__all__ = ["ekf_paper", "ekf", "iekf", "linearise_sensor", "DEFAULT_P0_SIGMA"]

#: default 1-sigma prior of the well-posed EKFs: zero-point error (mm) and direction tilt
#: (rad, 5.7 deg), wide enough to cover the assembly tolerance of a machined pressure foot
DEFAULT_P0_SIGMA = (2.0, 0.1)


def _chart_cov_from_raw(P6, u_nom):
    """Project a raw 6x6 covariance onto the chart (x, y, z, a, b) at small errors."""
    basis = direction_basis(u_nom[None])[0]  # (2, 3)
    T = np.zeros((5, 6))
    T[:3, :3] = np.eye(3)
    T[3:, 3:] = basis
    return T @ P6 @ T.T


# ---------------------------------------------------------------------------------------
# the paper's EKF


def ekf_paper(nominal: SensorLayout, obs: Observations, Q=1e-10, R=8e-5, delta=1e-4, P0=1.0,
              stop=True) -> Calibration:
    """The EKF of Eqs. 10-16 exactly as printed, one filter per sensor (filterpy).

    Parameters
    ----------
    nominal : SensorLayout
    obs : Observations
    Q : float
        Process noise, ``Q = Q I`` (6 x 6), mixed units as in the paper.
    R : float, mm^2
    delta : float
        Stopping rule ``||X_k - X_k-1|| < delta`` (mixed units).
    P0 : float
        ``P0 = P0 I``.
    stop : bool
        Stop at the rule (the paper) or run through all measurements.

    Returns
    -------
    Calibration
        ``theta`` is the raw estimate's direction normalised and projected on the chart;
        ``cov`` is ``P`` projected on the chart; ``raw_cov`` keeps ``P`` itself.
    """
    from filterpy.kalman import ExtendedKalmanFilter

    n = nominal.n
    theta = np.zeros((n, 5))
    cov = np.zeros((n, 5, 5))
    raw_cov = np.zeros((n, 6, 6))
    n_conv = np.full(n, -1)
    history = []
    for i in range(n):
        E0, u0 = nominal.zero[i], nominal.direction[i]
        kf = ExtendedKalmanFilter(dim_x=6, dim_z=1)
        kf.x = np.zeros((6, 1))
        kf.P = np.eye(6) * P0
        kf.Q = np.eye(6) * Q
        kf.R = np.array([[R]])
        hist = []
        for k, p in enumerate(_pose_order(obs, i)):
            N, D = obs.normal[p : p + 1], obs.offset[p : p + 1]
            d_nom = readings(E0[None], u0[None], N, D)[0][0, 0]
            z = np.array([[obs.d[p, i] - d_nom]])  # Z_k = d_meas - d_nom (Eq. 11)

            def H_jac(x, N=N, D=D):
                # H_k = J at the current estimate Phi_nom + X (Eq. 9)
                return jacobian_raw(E0[None] + x[:3, 0], u0[None] + x[3:, 0], N, D)[0]

            x_prev = kf.x.copy()
            kf.predict()  # Eqs. 12-13 (F = I)
            if not np.all(np.isfinite(H_jac(kf.x))):
                break  # the estimate left the region where the beam meets the datum
            kf.update(z, H_jac, lambda x, H_jac=H_jac: H_jac(x) @ x)  # Eqs. 14-16: Z - H X
            hist.append(kf.x[:, 0].copy())
            if np.linalg.norm(kf.x - x_prev) < delta and n_conv[i] < 0:
                n_conv[i] = k + 1
                if stop:
                    break
        history.append(np.array(hist).reshape(-1, 6))
        x = kf.x[:, 0]
        u = u0 + x[3:]
        unit = u / np.linalg.norm(u)
        basis = direction_basis(u0[None])[0]
        theta[i, :3] = x[:3]
        theta[i, 3:] = basis @ unit / (unit @ u0)
        raw_cov[i] = kf.P
        cov[i] = _chart_cov_from_raw(kf.P, u0)
    sigma = np.full(n, np.sqrt(R))
    return _finish("ekf_paper", nominal, obs, theta, cov, sigma, n_converged=n_conv, history=history, raw_cov=raw_cov)


# ---------------------------------------------------------------------------------------
# well-posed sequential filters on the five-parameter chart


def _prior(P0_sigma):
    s_pos, s_dir = P0_sigma
    return np.diag([s_pos**2] * 3 + [s_dir**2] * 2)


def _h_and_H(nominal, i, x, N, D):
    E = nominal.zero[i] + x[:3]
    u0 = nominal.direction[i][None]
    d = readings(E[None], direction_from_tangent(u0, x[None, 3:]), N, D)[0][0, 0]
    H = jacobian_tangent(E[None], u0, x[None, 3:], N, D)[0]  # (1, 5)
    return d, H


def _ekf_pass(nominal, i, obs, R, P0, Q, x_ref=None):
    """One filterpy EKF pass over sensor ``i``'s readings, from the prior ``N(0, P0)``.

    ``x_ref`` None: linearise at the running estimate (the ordinary EKF). Otherwise
    linearise every measurement at ``x_ref`` (a previous pass's estimate): with ``Q = 0``
    the pass is then one Gauss-Newton step on the MAP cost, in filter form.
    """
    from filterpy.kalman import ExtendedKalmanFilter

    kf = ExtendedKalmanFilter(dim_x=5, dim_z=1)
    kf.x = np.zeros((5, 1))
    kf.P = P0.copy()
    kf.Q = np.eye(5) * Q
    kf.R = np.array([[R]])
    hist = []
    for p in _pose_order(obs, i):
        N, D = obs.normal[p : p + 1], obs.offset[p : p + 1]
        if x_ref is None:
            HJ = lambda x, N=N, D=D: _h_and_H(nominal, i, x[:, 0], N, D)[1]  # noqa: E731
            Hx = lambda x, N=N, D=D: np.array([[_h_and_H(nominal, i, x[:, 0], N, D)[0]]])  # noqa: E731
        else:
            h_ref, H_ref = _h_and_H(nominal, i, x_ref, N, D)
            HJ = lambda x, H_ref=H_ref: H_ref  # noqa: E731
            Hx = lambda x, h_ref=h_ref, H_ref=H_ref: np.array([[h_ref]]) + H_ref @ (x - x_ref[:, None])  # noqa: E731
        kf.predict()
        kf.update(np.array([[obs.d[p, i]]]), HJ, Hx)
        hist.append(kf.x[:, 0].copy())
    return kf.x[:, 0].copy(), (kf.P + kf.P.T) / 2, np.array(hist).reshape(-1, 5)


def linearise_sensor(nominal, i, x, N, D, z):
    """Sensor ``i``'s readings linearised at the chart estimate ``x``.

    Parameters
    ----------
    nominal : SensorLayout, the layout the chart ``x`` is relative to
    x : (5,) float, mm and rad, zero-point offset (TCS) and beam tilt about the chart axes
    N : (m, 3) float, datum normal in the TCS; D : (m,) float, mm, datum offset in the TCS
    z : (m,) float, mm, the measured readings

    Returns
    -------
    H : (k, 5) float, the readings' Jacobian; r : (k,) float, mm, measured minus predicted;
    beams that miss the datum dropped (they tell nothing)
    """
    u0 = nominal.direction[i][None]
    E = nominal.zero[i][None] + x[:3]
    h = readings(E, direction_from_tangent(u0, x[None, 3:]), N, D)[0][:, 0]
    H = jacobian_tangent(E, u0, x[None, 3:], N, D)[:, 0, :]
    ok = np.isfinite(h) & np.all(np.isfinite(H), axis=1)
    return H[ok], (z - h)[ok]


def _residual_cov(nominal, i, obs, x):
    """Sensor ``i``'s scatter (mm) and residual-scaled covariance (5, 5) at the chart estimate ``x``."""
    from metrology.calibration.uncertainty import residual_scaled_cov

    rows = _pose_order(obs, i)
    return residual_scaled_cov(*linearise_sensor(nominal, i, x, obs.normal[rows], obs.offset[rows], obs.d[rows, i]))


def _sequential(name, nominal, obs, sigma_mm, P0_sigma, Q, passes, tol, stderr="stated"):
    sigma = _sigma(nominal, sigma_mm)
    if not np.all(np.isfinite(sigma)):
        raise ValueError(f"{name} needs the reading noise: give sigma_mm or noise_mm in the layout")
    n = nominal.n
    theta, cov, history = np.zeros((n, 5)), np.zeros((n, 5, 5)), []
    P0 = _prior(P0_sigma)
    for i in range(n):
        x, P, hist = _ekf_pass(nominal, i, obs, sigma[i] ** 2, P0, Q)
        hists = [hist]
        for _ in range(passes - 1):
            x_new, P, hist = _ekf_pass(nominal, i, obs, sigma[i] ** 2, P0, Q, x_ref=x)
            hists.append(hist)
            step = np.abs(x_new - x)
            x = x_new
            if np.all(step[:3] < tol[0]) and np.all(step[3:] < tol[1]):
                break
        theta[i], cov[i] = x, P
        if stderr == "residual":
            sigma[i], cov[i] = _residual_cov(nominal, i, obs, x)
        history.append(_raw_history(nominal, i, np.concatenate(hists)))
    return _finish(name, nominal, obs, theta, cov, sigma, history=history)


def ekf(nominal: SensorLayout, obs: Observations, sigma_mm=None, P0_sigma=DEFAULT_P0_SIGMA, Q=0.0,
        stderr="stated") -> Calibration:
    """filterpy EKF on the chart ``(x, y, z, a, b)`` with a consistent prior and ``h(x) = d(x)``.

    Parameters
    ----------
    sigma_mm : float or (n,) float, mm, optional
        Reading noise (default: the layout's ``noise_mm``); sets ``R = sigma^2``.
    P0_sigma : (float, float)
        Prior 1-sigma of the zero-point error (mm) and of the direction tilt (rad).
    Q : float
        Process noise on every state (default 0: the parameters are constant).
    stderr : ``"stated"`` (default, the filter's ``P``) or ``"residual"``, as :func:`iekf`'s.
    """
    if stderr not in ("stated", "residual"):
        raise ValueError(f"stderr {stderr!r}: expected 'stated' or 'residual'")
    return _sequential("ekf", nominal, obs, sigma_mm, P0_sigma, Q, 1, (0.0, 0.0), stderr)


def iekf(nominal: SensorLayout, obs: Observations, sigma_mm=None, P0_sigma=DEFAULT_P0_SIGMA, passes=10,
         tol=(1e-6, 1e-8), stderr="stated") -> Calibration:
    """Iterated EKF: passes of the filter, each linearised at the previous pass's estimate.

    Pass 1 is :func:`ekf`. Every later pass restarts from the prior ``N(0, P0)`` and
    linearises all measurements at the previous estimate, which with ``Q = 0`` is one
    Gauss-Newton step on the MAP cost; passes stop when the estimate moves less than
    ``tol`` (mm, rad). The result is the batch MAP estimate with the prior, in filter form.

    ``stderr``: ``"stated"`` (default) reports the filter's ``P`` (the stated noise and the
    prior); ``"residual"`` reports what :func:`lsq` reports, ``s^2 (J^T J)^-1`` at the estimate
    with ``s`` the residuals' scatter (:func:`metrology.calibration.uncertainty.residual_scaled_cov`),
    and ``sigma_mm`` then holds ``s`` (``calibrate --follow``).
    """
    if stderr not in ("stated", "residual"):
        raise ValueError(f"stderr {stderr!r}: expected 'stated' or 'residual'")
    return _sequential("iekf", nominal, obs, sigma_mm, P0_sigma, 0.0, passes, tol, stderr)


def _raw_history(nominal, i, hist5):
    """Chart history (k, 5) to the paper's raw errors (k, 6) for plotting."""
    if len(hist5) == 0:
        return np.zeros((0, 6))
    u0 = np.repeat(nominal.direction[i][None], len(hist5), axis=0)
    u = direction_from_tangent(u0, hist5[:, 3:])
    return np.concatenate([hist5[:, :3], u - u0], axis=1)

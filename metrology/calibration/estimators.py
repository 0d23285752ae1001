"""Estimators of the sensor parameters: the paper's EKF (section 3.2) and better ones.

All estimators share the measurement model of :mod:`metrology.core.model` and its analytic
Jacobian, take a nominal :class:`~metrology.layout.SensorLayout` and
:class:`Observations`, and return a :class:`Calibration` (a fitted copy of the layout
with standard errors); the input layout is never changed.

``ekf_paper``, ``ekf``, ``iekf``
    Kalman filters, sequential over the poses (:mod:`metrology.calibration.kalman`): the paper's EKF as printed,
    and the well-posed EKF and iterated EKF on the five-parameter chart.
``lsq``
    Batch nonlinear least squares (``scipy.optimize.least_squares``) on the readings: the
    base model of :class:`~metrology.calibration.engine.LeastSquares`, the engine the
    diagnosis' extended fits use too.
``method1``
    The paper's baseline (method 1): least squares on the plane-fitting residual, the
    distance from the point Eq. 17 predicts to the datum, with unit directions.

The result all of them return, and what they share in making it: :mod:`metrology.calibration.fitted`. Here the
batch least squares and the dispatch on a method's name (:data:`METHODS`).
"""

from __future__ import annotations

import numpy as np

from metrology.calibration.fitted import Calibration, _finish, _pose_order
from metrology.calibration.kalman import DEFAULT_P0_SIGMA, ekf, ekf_paper, iekf
from metrology.calibration.kept import Kept, content_key
from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, direction_from_tangent
from metrology.core.observations import Observations

__all__ = [
    "DEFAULT_METHOD",
    "Calibration",
    "calibrate",
    "ekf_paper",
    "ekf",
    "iekf",
    "lsq",
    "method1",
    "METHODS",
    "DEFAULT_P0_SIGMA",
]


#: the chart parameters' typical scales for the solver (mm, mm, mm, rad, rad)
LSQ_X_SCALE = np.array([1.0, 1.0, 1.0, 0.05, 0.05])


def _lsq_sensor(nominal, i, obs, residual, x0=None, loss="linear", f_scale=1.0):
    from scipy.optimize import least_squares

    rows = _pose_order(obs, i)
    if len(rows) < 5:
        raise ValueError(f"sensor {nominal.names[i]}: {len(rows)} readings, need at least 5 for 5 parameters")
    N, D, z = obs.normal[rows], obs.offset[rows], obs.d[rows, i]
    fun, jac = residual(nominal, i, N, D, z)
    sol = least_squares(fun, np.zeros(5) if x0 is None else x0, jac=jac, method="trf", loss=loss, f_scale=f_scale,
                        x_scale=LSQ_X_SCALE, xtol=1e-14, ftol=1e-14, gtol=1e-14,
                        max_nfev=200)
    if not np.all(np.isfinite(sol.x)):
        raise ValueError(f"sensor {nominal.names[i]}: least squares did not converge")
    J = sol.jac
    dof = max(len(rows) - 5, 1)
    s2 = float(np.sum(sol.fun**2) / dof)
    JTJ = J.T @ J
    cov = np.linalg.pinv(JTJ) * s2
    return sol.x, cov, np.sqrt(s2)


def _plane_residual(nominal, i, N, D, z):
    """Distance (mm) from the Eq. 17 point ``E + d u`` (unit u) to the datum."""
    u0 = nominal.direction[i][None]
    basis = direction_basis(u0)[0]  # (2, 3)

    def fun(x):
        E = nominal.zero[i] + x[:3]
        u = direction_from_tangent(u0, x[None, 3:])[0]
        return N @ E + D + z * (N @ u)

    def jac(x):
        u = direction_from_tangent(u0, x[None, 3:])[0]
        w = u0[0] + basis.T @ x[3:]
        wn = np.linalg.norm(w)
        du_dab = (basis.T - np.outer(u, u @ basis.T)) / wn  # (3, 2)
        return np.concatenate([N, z[:, None] * (N @ du_dab)], axis=1)

    return fun, jac


def lsq(nominal: SensorLayout, obs: Observations, loss="linear", f_scale=1.0) -> Calibration:
    """Batch nonlinear least squares on the readings, per sensor (``scipy.optimize.least_squares``).

    Standard errors are ``s^2 (J^T J)^-1`` with ``s`` the residual RMS (``m - 5`` degrees of
    freedom): honest also when the stated noise is wrong. ``sigma_mm`` reports ``s``.
    ``loss``, ``f_scale`` (mm, a scalar or ``(n,)`` per sensor): scipy's robust loss and the
    residual at which it starts to discount (a robust loss for screening only: its standard
    errors are the linearised least-squares ones).
    """
    n = nominal.n
    theta, cov, sig = np.zeros((n, 5)), np.zeros((n, 5, 5)), np.zeros(n)
    scale = np.broadcast_to(np.asarray(f_scale, float), (n,))
    for i in range(n):
        theta[i], cov[i], sig[i] = _lsq_base(nominal, i, obs, loss=loss, f_scale=float(scale[i]))
    return _finish("lsq", nominal, obs, theta, cov, sig)


#: sensor fits :func:`_lsq_base` keeps by the content of their problem (least recently used dropped
#: first). The export screen (``calibration.sanity``) fits the data as read and again under each likely
#: export mistake, and a mistake that moves two columns (or none of a sensor's) leaves the other
#: sensors' problems as read; ``calibrate`` then fits what its screen fitted. A kept fit is the one the
#: solver would return: the same inputs, the same arithmetic.
LSQ_KEPT = 64
_KEPT = Kept(LSQ_KEPT)


def _problem_key(nominal, i, obs, loss, f_scale) -> bytes:
    """A digest of everything sensor ``i``'s fit depends on: its nominal zero point and direction,
    the datum in each pose's TCS, its readings, the loss and its scale."""
    return content_key(nominal.zero[i], nominal.direction[i], obs.normal, obs.offset, obs.d[:, i], loss,
                       float(f_scale))


def _lsq_base(nominal, i, obs, loss="linear", f_scale=1.0):
    """Sensor ``i``'s base model by :class:`~metrology.calibration.engine.LeastSquares` (unit
    weights: residuals in mm): ``(theta (5,), cov (5, 5), s mm)``; a problem solved before is
    not solved again (:data:`LSQ_KEPT`)."""
    m = len(_pose_order(obs, i))
    if m < 5:
        raise ValueError(f"sensor {nominal.names[i]}: {m} readings, need at least 5 for 5 parameters")
    x, cov, s = _KEPT.get(_problem_key(nominal, i, obs, loss, f_scale),
                          lambda: _solve_base(nominal, i, obs, m, loss, f_scale))
    return x.copy(), cov.copy(), s


def _solve_base(nominal, i, obs, m, loss, f_scale):
    """:func:`_lsq_base`'s fit (``m`` the sensor's readings)."""
    from metrology.calibration.engine import LeastSquares

    p = LeastSquares(nominal, obs, np.ones(nominal.n), sensors=[i])
    x = p.solve("lsq", loss, f_scale=f_scale, x_scale=LSQ_X_SCALE, xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=200)
    if not np.all(np.isfinite(x)):
        raise ValueError(f"sensor {nominal.names[i]}: least squares did not converge")
    s2 = float(np.sum(p.result.fun**2) / max(m - 5, 1))
    # scipy's Jacobian at the solution: under a robust loss, weighted as its Gauss-Newton step was
    return x, p.covariance(x, s2, J=p.result.jac), np.sqrt(s2)


def method1(nominal: SensorLayout, obs: Observations) -> Calibration:
    """The paper's method 1: least squares on the plane-fitting residual (unit directions)."""
    n = nominal.n
    theta, cov, sig = np.zeros((n, 5)), np.zeros((n, 5, 5)), np.zeros(n)
    for i in range(n):
        theta[i], cov[i], sig[i] = _lsq_sensor(nominal, i, obs, _plane_residual)
    return _finish("method1", nominal, obs, theta, cov, sig)


#: the default estimator: on fixtures/measured, lsq and iekf recover the truth equally
#: well (README "Estimators compared"); lsq is the fastest and its standard errors are
#: scaled by the residual, so they stay honest when the stated noise is optimistic
DEFAULT_METHOD = "lsq"
#: estimator name -> function; ``calibrate`` dispatches on these
METHODS = {"ekf_paper": ekf_paper, "ekf": ekf, "iekf": iekf, "lsq": lsq, "method1": method1}


def calibrate(nominal: SensorLayout, obs: Observations, method: str = "lsq", **kwargs) -> Calibration:
    """Run the estimator ``method`` (a key of :data:`METHODS`) and return its fitted copy."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}, expected one of {', '.join(METHODS)}")
    return METHODS[method](nominal, obs, **kwargs)

"""The fitted copy of a layout that every estimator returns (:class:`Calibration`), and what the estimators
share in making it: each sensor's reading noise and poses, and the calibrated layout, its covariance and
residuals built from the chart errors (:func:`_finish`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.core.model import chart_cov_recentred, direction_from_tangent, readings
from metrology.core.observations import Observations

__all__ = ["Calibration"]


@dataclass(frozen=True)
class Calibration:
    """A fitted copy of the nominal layout.

    Attributes
    ----------
    method : str
    nominal : SensorLayout
    layout : SensorLayout
        Calibrated (unit directions), with ``zero_stderr_mm`` and ``direction_stderr_deg``.
    theta : (n, 5) float
        Chart errors ``(dx, dy, dz)`` mm and ``(a, b)`` rad around the nominal direction.
    cov : (n, 5, 5) float
        Covariance of ``theta`` (mm, rad).
    delta_raw : (n, 6) float
        The paper's error vector ``(dx, dy, dz, dm, dn, dq)``: zero mm, unit-direction change.
    n_used : (n,) int
        Readings used per sensor.
    n_converged : (n,) int
        EKF only: measurements to the stopping rule (-1: never met); absent (empty) otherwise.
    history : list of (k, 6) float arrays, per sensor
        EKF only: the raw error estimate after each measurement (Figures 7 and 11).
    residual_rms : (n,) float, mm
        RMS of ``d_measured - d_predicted`` per sensor, over the readings used to fit.
    sigma_mm : (n,) float, mm
        The reading noise the standard errors are scaled with.
    unidentified : str
        What the data cannot determine, in words (always the direction scale, the gauge).
    raw_cov : (n, 6, 6) float or None
        ``ekf_paper`` only: its ``P``, whose gauge direction ``(0, 0, 0, u)`` is never updated.
    datum : DatumNuisance or None
        The datum plane estimated with the sensors under the scan's covariance
        (:mod:`metrology.calibration.datum_prior`); None: the plane was taken as exact.
    """

    method: str
    nominal: SensorLayout
    layout: SensorLayout
    theta: np.ndarray
    cov: np.ndarray
    delta_raw: np.ndarray
    n_used: np.ndarray
    residual_rms: np.ndarray
    sigma_mm: np.ndarray
    n_converged: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    history: list = field(default_factory=list)
    unidentified: str = "direction scale (gauge): readings do not depend on |u|; directions are unit vectors"
    raw_cov: np.ndarray | None = None
    datum: object = None

    @property
    def stderr(self) -> np.ndarray:
        """(n, 5) float: standard errors of ``theta`` (mm, rad)."""
        return np.sqrt(np.maximum(np.einsum("nii->ni", self.cov), 0.0))


def _sigma(nominal: SensorLayout, sigma_mm):
    """Per-sensor reading sigma (n,) mm: the argument, else the layout's noise_mm, else NaN."""
    if sigma_mm is not None:
        return np.broadcast_to(np.asarray(sigma_mm, float), (nominal.n,)).copy()
    return nominal.noise_mm.copy()


def _finish(method, nominal, obs, theta, cov, sigma, **extra) -> Calibration:
    """Build the calibrated layout and residuals from chart errors ``theta (n, 5)``."""
    zero = nominal.zero + theta[:, :3]
    u = direction_from_tangent(nominal.direction, theta[:, 3:])
    pred, _ = readings(zero, u, obs.normal, obs.offset)
    res = obs.d - pred
    ok = np.isfinite(res)
    n_used = ok.sum(axis=0)
    rms = np.sqrt(np.nansum(np.where(ok, res, 0.0) ** 2, axis=0) / np.maximum(n_used, 1))
    se = np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
    # the layout states its covariance in the chart centred on its own (calibrated) directions;
    # sensors are fitted one by one from their own readings, so it is block diagonal
    from scipy.linalg import block_diag

    full = block_diag(*chart_cov_recentred(nominal.direction, theta[:, 3:], cov)) if np.all(np.isfinite(cov)) else None
    layout = nominal.with_params(zero, u, zero_stderr_mm=se[:, :3], direction_stderr_deg=np.rad2deg(se[:, 3:]),
                                 covariance=full)
    delta_raw = np.concatenate([theta[:, :3], u - nominal.direction], axis=1)
    return Calibration(method, nominal, layout, theta, cov, delta_raw, n_used, rms, sigma, **extra)


def _pose_order(obs: Observations, i: int):
    """Indices of the poses with a reading of sensor ``i``, in file order."""
    return np.flatnonzero(np.isfinite(obs.d[:, i]))

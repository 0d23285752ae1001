"""Calibration pose by pose, live: the iterated EKF as the cell takes the poses, with a stopping rule.

After every pose each sensor's five chart parameters ``(x, y, z, a, b)`` get the iterated EKF's
measurement update in information form: with the prior ``N(0, P0)`` of the filters and the
readings so far, each iteration relinearises every reading's model ``h(x) = d(x)``
(:mod:`metrology.core.model`) at the current estimate ``x_j`` and solves

    M = P0^-1 + sum H^T H / R,   M x_{j+1} = sum H^T (z - h(x_j) + H x_j) / R   (a Cholesky solve),

until the step is below ``tol`` (a Gauss-Newton step on the MAP cost: the passes of
:func:`~metrology.calibration.kalman.iekf`, warm-started from the previous pose's estimate).
A one-pass recursive EKF would keep the Jacobians of its first, wrong estimates: on the bundled
measured run its last estimate is 11 standard errors from the batch optimum; this one is the
batch optimum on the poses so far after every pose.

The standard errors are the ones ``calibrate`` reports
(:func:`metrology.calibration.uncertainty.residual_scaled_cov` of the readings so far:
``s^2 (J^T J)^-1`` with ``s`` the residuals' scatter over ``m - 5`` degrees of freedom, no
prior), not ``M^-1`` of the stated noise: when the residuals exceed the stated noise the model
misses something and the stated noise would claim a precision the data do not show. With five
readings or fewer a sensor's sigma is inf (no redundancy to measure the scatter). The normal's
predicted 1-sigma at the working stand-off is :func:`metrology.calibration.uncertainty.normal_sigma`
of that covariance.

The targets are met when every sensor's largest zero-point sigma, largest tilt sigma and (if
given) the normal's sigma are at or below them: the paper's "convergence measurement points"
(Table 3) made into a rule with a stated meaning, one standard error below the target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.calibration.kalman import DEFAULT_P0_SIGMA, linearise_sensor
from metrology.calibration.uncertainty import normal_sensitivity, normal_sigma, residual_scaled_cov
from metrology.core.frames import plane_in_tcs
from metrology.core.layout import SensorLayout

__all__ = ["FollowStep", "Follower", "Targets"]


@dataclass(frozen=True)
class Targets:
    """Wanted 1-sigma: ``zero_mm`` (mm), ``tilt_rad`` (rad) and ``normal_rad`` (rad, or None: not used)."""

    zero_mm: float
    tilt_rad: float
    normal_rad: float | None = None

    def met(self, stderr, normal_sigma_rad) -> bool:
        ok = stderr[:, :3].max() <= self.zero_mm and stderr[:, 3:].max() <= self.tilt_rad
        return bool(ok and (self.normal_rad is None or normal_sigma_rad <= self.normal_rad))

    def to_dict(self) -> dict:
        return {"zero_mm": self.zero_mm, "tilt_deg": float(np.rad2deg(self.tilt_rad)),
                "normal_deg": None if self.normal_rad is None else float(np.rad2deg(self.normal_rad))}


@dataclass(frozen=True)
class FollowStep:
    """The state after one pose.

    Attributes
    ----------
    k : int, poses taken; pose_id : str; names : tuple of str
    theta : (n, 5) float, mm and rad, the chart errors estimated so far
    stderr : (n, 5) float, mm and rad
    normal_sigma_rad : float, rad
    met : bool, every target met at this pose
    """

    k: int
    pose_id: str
    names: tuple
    theta: np.ndarray
    stderr: np.ndarray
    normal_sigma_rad: float
    met: bool


class Follower:
    """The live filter of ``metro calibrate --follow`` (module docstring).

    Parameters
    ----------
    nominal : SensorLayout, the chart centres
    plane_normal : (3,) float, unit, tracker frame; plane_offset : float, mm
    sigma_mm : (n,) float, mm, stated reading noise (R = sigma^2 of the filter's update; the
        reported standard errors are scaled by the residuals, module docstring)
    targets : Targets
    standoff_mm : float, mm, the working stand-off of the normal's sigma
    P0_sigma : (float, float), the prior's 1-sigma, mm and rad
    """

    def __init__(self, nominal: SensorLayout, plane_normal, plane_offset, sigma_mm, targets: Targets,
                 standoff_mm: float, P0_sigma=DEFAULT_P0_SIGMA, iterations: int = 10, tol=(1e-7, 1e-9)):
        self.nominal = nominal
        self.normal = np.asarray(plane_normal, float)
        self.offset = float(plane_offset)
        self.R = np.asarray(sigma_mm, float) ** 2
        self.targets = targets
        self.G = normal_sensitivity(nominal, standoff_mm)
        s_pos, s_dir = P0_sigma
        self.P0inv = np.diag([s_pos**-2.0] * 3 + [s_dir**-2.0] * 2)  # the prior N(0, P0) in information form
        self.x = np.zeros((nominal.n, 5))
        self.P = np.full((nominal.n, 5, 5), np.inf)  # the reported covariance; no reading yet: nothing determined
        self.scale = np.full(nominal.n, np.inf)  # mm, the residuals' scatter per sensor
        self.data = [[] for _ in range(nominal.n)]
        self.iterations, self.tol = iterations, tol
        self.k = 0
        self.met_at = None

    def _update(self, i):
        from scipy.linalg import cho_factor, cho_solve

        N, D, z = (np.array(v) for v in zip(*self.data[i]))
        x = self.x[i].copy()
        for _ in range(self.iterations):
            H, r = linearise_sensor(self.nominal, i, x, N, D, z)
            M = self.P0inv + H.T @ H / self.R[i]  # symmetric positive definite (the prior)
            x_new = cho_solve(cho_factor(M), H.T @ (r + H @ x) / self.R[i])
            step = np.abs(x_new - x)
            x = x_new
            if np.all(step[:3] < self.tol[0]) and np.all(step[3:] < self.tol[1]):
                break
        self.x[i] = x
        self.scale[i], self.P[i] = residual_scaled_cov(*linearise_sensor(self.nominal, i, x, N, D, z))

    def add(self, pose_id: str, rot, trans, d) -> FollowStep:
        """Update with one pose: ``rot (3, 3)`` and ``trans (3,)`` mm, tcs2tracker; ``d (n,)`` mm, NaN = no reading."""
        N, D = plane_in_tcs(self.normal, self.offset, np.asarray(rot, float)[None], np.asarray(trans, float)[None])
        for i, z in enumerate(np.asarray(d, float)):
            if np.isfinite(z):
                self.data[i].append((N[0], float(np.atleast_1d(D)[0]), float(z)))
                self._update(i)
        self.k += 1
        se = np.sqrt(np.maximum(np.einsum("nii->ni", self.P), 0.0))
        ns = normal_sigma(self.G, self.P)
        met = self.targets.met(se, ns)
        if met and self.met_at is None:
            self.met_at = (self.k, str(pose_id))
        return FollowStep(self.k, str(pose_id), self.nominal.names, self.x.copy(), se, ns, met)

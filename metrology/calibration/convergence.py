"""How a calibration converges and where its residuals fall: the data behind the figures."""

from __future__ import annotations

import numpy as np

from metrology.calibration.dataset import MIN_READINGS
from metrology.calibration.estimators import DEFAULT_METHOD, calibrate
from metrology.core.layout import SensorLayout
from metrology.core.model import readings
from metrology.core.observations import Observations

__all__ = ["batch_convergence", "residual_table"]


def batch_convergence(nominal: SensorLayout, obs: Observations, method: str = DEFAULT_METHOD, start: int = MIN_READINGS):
    """Estimates after the first k poses, k = start..p: the convergence of a batch method.

    Returns
    -------
    list, per sensor, of (k (q,) int, theta (q, 5) float mm/rad, stderr (q, 5) float mm/rad)
        ``k`` counts the poses used (all sensors share the pose prefix).
    """
    p = obs.n_poses
    ks, th, se = [], [], []
    for k in range(start, p + 1):
        sub = obs.select(np.arange(k))
        if np.any(np.isfinite(sub.d).sum(axis=0) < MIN_READINGS):
            continue
        cal = calibrate(nominal, sub, method)
        ks.append(k)
        th.append(cal.theta)
        se.append(cal.stderr)
    th, se = np.array(th).reshape(-1, nominal.n, 5), np.array(se).reshape(-1, nominal.n, 5)
    return [(np.array(ks), th[:, i], se[:, i]) for i in range(nominal.n)]


def residual_table(layout: SensorLayout, obs: Observations):
    """Residuals of the readings under ``layout`` and where they occur.

    Returns
    -------
    residual : (p, n) float, mm, measured - predicted; NaN where no reading
    incidence_deg : (p, n) float, deg, angle between the beam and the datum normal
    """
    pred, _ = readings(layout.zero, layout.direction, obs.normal, obs.offset)
    cos = np.abs(obs.normal @ layout.direction.T)
    return obs.d - pred, np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0)))

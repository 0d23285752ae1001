"""Synthetic plate clouds with a known plane, and the checks the datum tests share."""

import math

import numpy as np

from metrology.core.plane import Plane

CHI2_2DOF_3SIGMA = -2 * math.log(1 - 0.9973002039367398)  # P(chi2_2 <= x) = P(|z| <= 3)


def random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def plate_cloud(rng, m, sigma=0.02, outliers=0.05, amp=5.0, size=(400.0, 300.0), shift=500.0, form=None):
    """Points on z = 0 (+ form) in a plate frame, noise along every axis, symmetric gross
    outliers up to ``amp`` mm off the plate, then a random rigid transform.

    Returns points (m, 3) mm, the true Plane, the rotation (3, 3) and translation (3,).
    """
    u = rng.uniform(-size[0] / 2, size[0] / 2, m)
    v = rng.uniform(-size[1] / 2, size[1] / 2, m)
    w = np.zeros(m) if form is None else form(u, v)
    local = np.column_stack([u, v, w]) + rng.normal(0.0, sigma, (m, 3))
    bad = rng.random(m) < outliers
    local[bad, 2] += rng.uniform(-amp, amp, bad.sum())
    R, t = random_rotation(rng), rng.uniform(-shift, shift, 3)
    return local @ R.T + t, Plane(R[:, 2], -float(R[:, 2] @ t)), R, t


def normal_angle_deg(a, b):
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), abs(a @ b)))


def normal_chi2(fit, truth):
    """Mahalanobis distance^2 of the normal's error in the plane's 2 tilt directions."""
    n = fit.plane.normal
    t = truth.normal if truth.normal @ n > 0 else -truth.normal
    E = fit.axes  # (2, 3) in-plane
    err = E @ (t - n)
    C = E @ fit.covariance[:3, :3] @ E.T
    return float(err @ np.linalg.solve(C, err))


def aligned(truth, fit):
    """The truth's (normal, offset) with the fit's sign."""
    s = 1.0 if truth.normal @ fit.plane.normal > 0 else -1.0
    return s * truth.normal, s * truth.offset

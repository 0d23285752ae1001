"""Noise scales of the datum fit: the least-quantile-of-squares scale, and the Gaussian
truncated to the inlier window (for the threshold refinement and the fit's covariance)."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from metrology.core.tolerances import COLLINEAR_RTOL

__all__ = ["lqs_scale", "truncated_normal_std", "window_sigmas", "INLIER_K_SIGMA"]

#: default inlier threshold, in robust standard deviations of the residuals (unitless)
INLIER_K_SIGMA = 3.0
#: least-quantile-of-squares search: points scored, plane hypotheses, and the quantile
#: of absolute residuals minimised (0.25: breakdown at 75 % outliers)
LQS_POINTS = 1000
LQS_HYPOTHESES = 500
LQS_QUANTILE = 0.25


def truncated_normal_std(k: float) -> float:
    """Standard deviation of a standard normal variable truncated to ``[-k, k]`` (unitless)."""
    phi = math.exp(-0.5 * k * k) / math.sqrt(2 * math.pi)
    mass = math.erf(k / math.sqrt(2))
    return math.sqrt(1.0 - 2.0 * k * phi / mass)


def window_sigmas(threshold: float, sigma_kept: float) -> float:
    """The window half-width ``k`` (in noise sigmas) that leaves Gaussian residuals
    truncated to ``+-threshold`` with standard deviation ``sigma_kept``.

    Solves ``g(k) / k = sigma_kept / threshold`` (``g`` = :func:`truncated_normal_std`),
    decreasing from ``1/sqrt(3)`` at ``k -> 0`` (residuals filling the window evenly) to 0.
    Clamped to ``[1, 40]``: below 1 the Gaussian model does not describe the residuals,
    above 40 the window is wide open. Unitless.
    """
    if not (threshold > 0) or not (sigma_kept >= 0):
        return math.inf
    target = sigma_kept / threshold
    lo, hi = 1.0, 40.0
    if target >= truncated_normal_std(lo) / lo:
        return lo
    if target <= truncated_normal_std(hi) / hi:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if truncated_normal_std(mid) / mid > target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def lqs_scale(points, rng, n_hypotheses=LQS_HYPOTHESES, quantile=LQS_QUANTILE):
    """Least-quantile-of-squares plane and its Gaussian-consistent residual scale.

    Parameters
    ----------
    points : (k, 3) float, mm, cloud frame; k >= 4
    rng : numpy.random.Generator
    n_hypotheses : int
        Planes tried, each through 3 random points.
    quantile : float
        Quantile of the absolute residuals minimised, in (0, 1).

    Returns
    -------
    sigma : float, mm
        ``Q_q(|r|) / Phi^-1((1 + q) / 2)`` for the best plane (the 3 points defining each
        plane are left out of its quantile).
    plane : (4,) float
        ``(A, B, C, D)`` of the best hypothesis.
    """
    pts = np.asarray(points, dtype=float)
    k = len(pts)
    if k < 4:
        raise ValueError(f"need at least 4 points for a robust scale, got {k}")
    tri = np.sort(rng.integers(0, k, size=(n_hypotheses, 3)), axis=1)
    p0, p1, p2 = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    nrm = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(nrm, axis=1)
    span = np.maximum(np.linalg.norm(p1 - p0, axis=1), np.linalg.norm(p2 - p0, axis=1))
    ok = (length > COLLINEAR_RTOL * span**2) & (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2])
    if not ok.any():
        raise ValueError("points are collinear (or coincident): no unique plane")
    nrm = nrm[ok] / length[ok, None]
    d = -np.einsum("ij,ij->i", nrm, p0[ok])
    ref = pts.mean(axis=0)
    absr = np.abs((pts - ref) @ nrm.T + (d + nrm @ ref))  # (k, h), referred to the centroid
    # the 3 defining points have r = 0: skip them in the order statistic
    rank = min(k - 1, 3 + int(math.ceil(quantile * (k - 3))) - 1)
    qv = np.partition(absr, rank, axis=0)[rank]
    best = int(np.argmin(qv))
    z = NormalDist().inv_cdf(0.5 * (1.0 + quantile))  # stdlib: scipy.stats costs 0.3 s to import
    return float(qv[best] / z), np.append(nrm[best], d[best])


"""The datum plane ``A x + B y + C z + D = 0`` and its total-least-squares fit.

Sign convention: ``(A, B, C)`` is a unit normal; the sign is chosen so that the offset
``D <= 0``, i.e. the normal points from the frame origin towards the plane (for a plane
through the origin, the largest-magnitude component of the normal is positive).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from metrology.core.model import direction_basis
from metrology.core.tolerances import COLLINEAR_RTOL

__all__ = ["Plane", "fit_plane_tls", "principal_axes", "plane_basis", "canonical_sign"]


def canonical_sign(normal, offset):
    """Apply metro's sign convention: unit normal, ``D <= 0`` (ties: largest |component| > 0)."""
    normal = np.asarray(normal, dtype=float)
    scale = np.linalg.norm(normal)
    if not np.isfinite(scale) or scale == 0:
        raise ValueError(f"plane normal {normal.tolist()} is not a direction")
    normal = normal / scale
    offset = float(offset) / scale
    flip = offset > 0 or (offset == 0 and normal[np.argmax(np.abs(normal))] < 0)
    return (-normal, -offset) if flip else (normal, offset)


@dataclass(frozen=True)
class Plane:
    """A plane ``normal . p + offset = 0``.

    Attributes
    ----------
    normal : (3,) float, unit, in the frame of the data it was fitted to
    offset : float, mm
    """

    normal: np.ndarray
    offset: float

    def __post_init__(self):
        n, d = canonical_sign(self.normal, self.offset)
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "offset", d)

    @property
    def coefficients(self):
        """``(A, B, C, D)`` as a (4,) float array."""
        return np.append(self.normal, self.offset)

    def distance(self, points):
        """Signed distances ``(m,)`` mm of points ``(m, 3)`` mm (positive on the normal's side)."""
        return np.asarray(points, dtype=float) @ self.normal + self.offset

    @classmethod
    def from_json(cls, path):
        """Read the JSON ``metro fit-plane --out`` writes (needs ``normal`` and ``offset``)."""
        try:
            with open(path, encoding="utf-8") as fh:
                data = json.load(fh)
            normal = np.asarray(data["normal"], dtype=float)
            offset = float(data["offset"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: not a plane JSON with 'normal' [A, B, C] and 'offset' D ({exc})") from None
        if normal.shape != (3,) or not np.all(np.isfinite(normal)) or not np.isfinite(offset):
            raise ValueError(f"{path}: 'normal' must be 3 finite numbers and 'offset' finite")
        return cls(normal, offset)


def fit_plane_tls(points):
    """Total-least-squares plane through points (no outlier rejection).

    Parameters
    ----------
    points : (m, 3) float, mm, any frame; m >= 3, not collinear

    Returns
    -------
    plane : Plane
        In the frame of ``points``.
    cov : (4, 4) float
        Covariance of ``(A, B, C, D)`` from the residual scatter (first order), with
        the normal's scale direction removed.
    rms : float, mm
        RMS orthogonal residual.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise ValueError(f"need at least 3 points of (x, y, z), got shape {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points contain NaN or inf")
    centroid = pts.mean(axis=0)
    q = pts - centroid
    _, sv, vt = np.linalg.svd(q, full_matrices=False)
    if sv[1] <= COLLINEAR_RTOL * max(sv[0], 1e-300):
        raise ValueError("points are collinear (or coincident): no unique plane")
    normal = vt[2]
    m = len(pts)
    dof = max(m - 3, 1)
    sigma2 = sv[2] ** 2 / dof
    # first-order covariance of the normal: tilt about the two in-plane axes
    cov_n = sigma2 * (np.outer(vt[0], vt[0]) / sv[0] ** 2 + np.outer(vt[1], vt[1]) / sv[1] ** 2)
    plane = Plane(normal, -float(normal @ centroid))
    # D = -n . c: dD = -c . dn - n . dc, var(n . dc) = sigma2 / m (a sign flip of
    # (n, D) leaves the covariance unchanged)
    J = np.zeros((4, 3))
    J[:3] = np.eye(3)
    J[3] = -centroid
    cov = J @ cov_n @ J.T
    cov[3, 3] += sigma2 / m
    rms = float(sv[2] / np.sqrt(m))
    return plane, cov, rms


def principal_axes(points):
    """Total-least-squares plane of ``points`` by the eigen-decomposition of their scatter.

    The same plane as :func:`fit_plane_tls` (which takes the SVD, better conditioned for a
    few points, and adds the covariance); this form returns the scatter's eigenvalues,
    which the robust datum fit needs, and no checks.

    Parameters
    ----------
    points : (k, 3) float, mm, any frame

    Returns
    -------
    centroid : (3,) float, mm
    normal : (3,) float, unit
        Eigenvector of the smallest eigenvalue (sign as ``numpy.linalg.eigh`` returns it).
    evals : (3,) float, mm^2
        Eigenvalues of the scatter matrix ``sum (p - c)(p - c)^T``, ascending.
    evecs : (3, 3) float
        The eigenvectors as columns, in the order of ``evals``.
    """
    c = points.mean(axis=0)
    q = points - c
    evals, evecs = np.linalg.eigh(q.T @ q)
    return c, evecs[:, 0], evals, evecs


def plane_basis(normal):
    """Two unit vectors ``(2, 3)`` spanning the plane perpendicular to ``normal (3,)``
    (:func:`metrology.core.model.direction_basis` of one vector)."""
    return direction_basis(np.asarray(normal, float)[None])[0]

"""Surface normal measurement and attitude adjustment, paper section 4 (Eqs. 17-22).

Normals returned here are unit vectors in the TCS, oriented towards the sensors (against
the mean beam direction), so a normal measured by any method can be compared directly.
"""

from __future__ import annotations

import numpy as np

from metrology.core.model import vector_norm
from metrology.core.tolerances import UNIT_NORM

__all__ = [
    "projection_points",
    "normal_eq18",
    "normal_lsq",
    "micro_plane_normal",
    "attitude_angles",
    "normal_from_angles",
    "rot_x",
    "rot_y",
    "rot_z",
    "angle_between",
]


def projection_points(zero, direction, d):
    """Projection points ``S = E + d u`` (Eq. 17).

    Parameters
    ----------
    zero : (n, 3) float, mm, TCS
    direction : (n, 3) float, unit, TCS
        Must be unit: Eq. 17 with a non-unit direction puts the point at the wrong
        distance, so a non-unit direction is an error, not something to fix silently.
    d : (p, n) float, mm
        Readings; NaN stays NaN.

    Returns
    -------
    S : (p, n, 3) float, mm, TCS
    """
    zero = np.asarray(zero, dtype=float)
    direction = np.asarray(direction, dtype=float)
    norms = vector_norm(direction, axis=1)
    if np.any(np.abs(norms - 1.0) > UNIT_NORM):
        raise ValueError(f"Eq. 17 needs unit beam directions, got norms {np.round(norms, 9).tolist()}")
    d = np.atleast_2d(np.asarray(d, dtype=float))
    return zero[None, :, :] + d[..., None] * direction[None, :, :]


def _orient(n, toward):
    """Flip normals ``(p, 3)`` so that ``n . toward >= 0``; normalise."""
    n = n / vector_norm(n, axis=-1, keepdims=True)
    sign = np.where(np.add.reduce(n * toward, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return n * sign


def _cross(a, b):
    """``np.cross(a, b)`` of ``(..., 3)`` float arrays with the same products and differences
    (so the same bits), without its axis moves."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def normal_eq18(S, toward=(0.0, 0.0, 1.0)):
    """Micro-plane normal of four projection points by Eqs. 18-19.

    Parameters
    ----------
    S : (p, 4, 3) float, mm, TCS
        Projection points in the order of the sensors around the foot.
    toward : (3,) float, TCS
        The normal is oriented so that ``n . toward >= 0``.

    Returns
    -------
    n : (p, 3) float, unit, TCS
        Mean of the four corner normals (Eq. 19), normalised.
    """
    S = np.asarray(S, dtype=float)
    if S.shape[-2:] != (4, 3):
        raise ValueError(f"Eqs. 18-19 need exactly 4 projection points, got shape {S.shape}")
    # the four corners' edges at once: (S2 - S1, S4 - S1, S3 - S2, S4 - S3), then the corner normals
    # S21 x S41, S21 x S32, S32 x S43, S41 x S43 as one (..., 4, 3) array
    edge = S[..., [1, 3, 2, 3], :] - S[..., [0, 0, 1, 2], :]
    corners = _cross(edge[..., [0, 0, 2, 1], :], edge[..., [1, 2, 3, 3], :])
    corners = corners / vector_norm(corners, axis=-1, keepdims=True)
    return _orient(sum(corners[..., i, :] for i in range(4)) / 4.0, np.asarray(toward, dtype=float))


def normal_lsq(S, toward=(0.0, 0.0, 1.0)):
    """Least-squares (orthogonal) plane normal through n >= 3 projection points per pose.

    Parameters
    ----------
    S : (p, n, 3) float, mm, TCS
        NaN rows (missing readings) are ignored; a pose with fewer than 3 points gives NaN.
    toward : (3,) float, TCS

    Returns
    -------
    n : (p, 3) float, unit, TCS; NaN where fewer than 3 finite points
    """
    S = np.asarray(S, dtype=float)
    if S.ndim != 3 or S.shape[-1] != 3 or S.shape[1] < 3:
        raise ValueError(f"need (p, n>=3, 3) projection points, got shape {S.shape}")
    ok = np.all(np.isfinite(S), axis=-1)  # (p, n)
    out = np.full(S.shape[:1] + (3,), np.nan)
    toward = np.asarray(toward, dtype=float)
    full = np.all(ok, axis=1)
    if np.any(full):
        Q = S[full] - S[full].mean(axis=1, keepdims=True)
        _, _, vt = np.linalg.svd(Q)
        out[full] = _orient(vt[:, 2, :], toward)
    for i in np.flatnonzero(~full & (ok.sum(axis=1) >= 3)):
        Q = S[i, ok[i]] - S[i, ok[i]].mean(axis=0)
        out[i] = _orient(np.linalg.svd(Q)[2][2][None], toward)[0]
    return out


def micro_plane_normal(zero, direction, d, method="auto"):
    """Micro-plane normal from sensor parameters and readings.

    Parameters
    ----------
    zero : (n, 3) float, mm, TCS
    direction : (n, 3) float, unit, TCS
    d : (p, n) float, mm
    method : {"auto", "eq18", "lsq"}
        ``eq18`` needs 4 sensors; ``auto`` uses it for 4 sensors with all readings and
        the least-squares plane otherwise.

    Returns
    -------
    n : (p, 3) float, unit, TCS, oriented against the mean beam direction
    """
    S = projection_points(zero, direction, d)
    toward = -np.mean(np.asarray(direction, dtype=float), axis=0)
    if method == "eq18" or (method == "auto" and S.shape[1] == 4 and np.all(np.isfinite(S))):
        return normal_eq18(S, toward)
    if method not in ("auto", "lsq", "eq18"):
        raise ValueError(f"method must be 'auto', 'eq18' or 'lsq', got {method!r}")
    return normal_lsq(S, toward)


def rot_x(a):
    """``Rot(X, a)`` of Eq. 21, ``(3, 3)``; ``a`` in rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    """``Rot(Y, a)`` of Eq. 21, ``(3, 3)``; ``a`` in rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    """``Rot(Z, a)`` of Eq. 21, ``(3, 3)``; ``a`` in rad."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def attitude_angles(n):
    """Attitude angles of Eq. 22 that turn the tool axis ``e_z`` onto ``n``.

    With ``n = Rot(Z, varphi) Rot(Y, theta) Rot(X, phi) e_z`` (Eq. 20) and ``varphi = 0``:
    ``n = (sin(theta) cos(phi), -sin(phi), cos(theta) cos(phi))``, so

        theta = atan(n_x / n_z),    phi = -asin(n_y)                     (Eq. 22)

    Parameters
    ----------
    n : (..., 3) float, TCS, with ``n_z > 0`` (normalised here)

    Returns
    -------
    theta, phi : (...) float, rad, in (-pi/2, pi/2)
    """
    n = np.asarray(n, dtype=float)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    if np.any(n[..., 2] <= 0):
        raise ValueError("Eq. 22 needs the normal on the tool-axis side (n_z > 0)")
    theta = np.arctan(n[..., 0] / n[..., 2])
    phi = -np.arcsin(np.clip(n[..., 1], -1.0, 1.0))
    return theta, phi


def normal_from_angles(theta, phi, varphi=0.0):
    """Rebuild ``n = Rot(Z, varphi) Rot(Y, theta) Rot(X, phi) e_z`` (Eq. 20); angles in rad."""
    theta, phi, varphi = np.broadcast_arrays(
        np.asarray(theta, float), np.asarray(phi, float), np.asarray(varphi, float)
    )
    out = np.empty(theta.shape + (3,))
    for idx in np.ndindex(theta.shape):
        out[idx] = rot_z(varphi[idx]) @ rot_y(theta[idx]) @ rot_x(phi[idx]) @ np.array([0.0, 0.0, 1.0])
    return out


def angle_between(a, b, oriented=False):
    """Angle (rad) between vectors ``(..., 3)``; unoriented (lines) unless ``oriented``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    dot = np.sum(a * b, axis=-1)
    if not oriented:
        dot = np.abs(dot)
    return np.arctan2(cross, dot)

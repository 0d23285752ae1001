"""Rigid transforms between the tracker frame and the tool frame (TCS).

Quaternions are scalar-first ``(w, x, y, z)`` everywhere in metro (files included); they
are converted explicitly where scipy (scalar-last) is called. A pose is ``tcs2tracker``:
``p_tracker = R p_tcs + t``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "matrix_from_quaternion",
    "quaternion_from_matrix",
    "plane_in_tcs",
    "points_tracker_from_tcs",
    "random_rotation",
]


def matrix_from_quaternion(q):
    """Rotation matrices from unit quaternions.

    Parameters
    ----------
    q : (..., 4) float
        Scalar-first ``(w, x, y, z)``; normalised here.

    Returns
    -------
    R : (..., 3, 3) float
    """
    from scipy.spatial.transform import Rotation

    q = np.asarray(q, dtype=float)
    flat = q.reshape(-1, 4)
    R = Rotation.from_quat(flat[:, [1, 2, 3, 0]]).as_matrix()
    return R.reshape(q.shape[:-1] + (3, 3))


def quaternion_from_matrix(R):
    """Unit quaternions ``(w, x, y, z)``, ``w >= 0``, from rotation matrices ``(..., 3, 3)``."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


def plane_in_tcs(normal_tracker, offset_tracker, tcs2tracker_rot, tcs2tracker_trans):
    """Express one tracker-frame plane in the TCS of every pose.

    Parameters
    ----------
    normal_tracker : (3,) float, unit, tracker frame
    offset_tracker : float, mm
        The plane ``N . p + D = 0`` in the tracker frame.
    tcs2tracker_rot : (p, 3, 3) float
    tcs2tracker_trans : (p, 3) float, mm, tracker frame

    Returns
    -------
    normal_tcs : (p, 3) float, unit, TCS
    offset_tcs : (p,) float, mm
    """
    n = np.asarray(normal_tracker, dtype=float)
    R = np.asarray(tcs2tracker_rot, dtype=float)
    t = np.asarray(tcs2tracker_trans, dtype=float)
    normal_tcs = np.einsum("pji,j->pi", R, n)
    offset_tcs = float(offset_tracker) + t @ n
    return normal_tcs, offset_tcs


def points_tracker_from_tcs(points_tcs, tcs2tracker_rot, tcs2tracker_trans):
    """Map points ``(p, n, 3)`` mm TCS to the tracker frame with per-pose transforms."""
    return np.einsum("pij,pnj->pni", tcs2tracker_rot, points_tcs) + tcs2tracker_trans[:, None, :]


def random_rotation(rng: np.random.Generator, size=None):
    """Uniformly random rotation matrices ``(3, 3)`` or ``(size, 3, 3)`` from ``rng``."""
    from scipy.spatial.transform import Rotation

    R = Rotation.random(1 if size is None else size, random_state=rng).as_matrix()
    return R[0] if size is None else R

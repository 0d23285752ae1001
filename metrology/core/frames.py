"""Rigid transforms between the tracker frame and the tool frame (TCS).

Quaternions are scalar-first ``(w, x, y, z)`` everywhere in metro (files included); they
are converted explicitly where scipy (scalar-last) is called. A pose is ``tcs2tracker``:
``p_tracker = R p_tcs + t``.
"""

from __future__ import annotations

import numpy as np

from metrology.core.sym2 import eig2

__all__ = [
    "tangent_frame",
    "principal_curvatures",
    "embed_shape",
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


def tangent_frame(n):
    """A surface's tangent frame at unit normals ``n (m, 3)``: ``e1`` (the frame's x made square to
    ``n``; its y where ``n`` is near x) and ``e2 = n x e1``, ``(m, 3)`` unit each, in ``n``'s frame."""
    ref = np.where(np.abs(n[:, 0:1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    e1 = ref - (ref * n).sum(1, keepdims=True) * n
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(n, e1)


def principal_curvatures(Kl):
    """``(m, 2)`` 1/mm: the eigenvalues (descending) of the symmetric 2 x 2 curvature tensors
    ``Kl (m, 2, 2)`` 1/mm written in a tangent frame."""
    return np.stack(eig2(Kl[:, 0, 0], Kl[:, 0, 1], Kl[:, 1, 1]), axis=1)


def embed_shape(Kl, e1, e2):
    """``(m, 3, 3)`` 1/mm: the shape operator ``sum_ab Kl_ab e_a e_b^T`` of the tangent-frame tensors
    ``Kl (m, 2, 2)`` on the tangent frame ``e1, e2 (m, 3)`` (:func:`tangent_frame`), in its frame."""
    E = np.stack([e1, e2], axis=1)  # (m, 2, 3)
    return np.einsum("mai,mab,mbj->mij", E, Kl, E)

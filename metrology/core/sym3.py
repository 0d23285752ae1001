"""Symmetric 3 x 3 matrices over arrays of holes, in closed form: each matrix given by its 6
entries ``(00, 01, 02, 11, 12, 22)`` as ``(h,)`` arrays (long inner loops, no per-hole LAPACK call):
the smallest eigenvector, the inverse, a shape operator turned by the smallest rotation onto a
tilted normal, and the null vector of a 4 x 3 matrix (the fit of :mod:`metrology.measure.surface`)."""

from __future__ import annotations

import numpy as np

__all__ = ["smallest_eigvec", "inv3", "smallest_rotation", "turned", "turned_tangent", "full", "null_vector_cols",
           "ADJ_STEPS", "GAP_MAX"]

#: products with the adjugate: each multiplies the other eigenvectors' share by ``lambda_3 / lambda_2``
ADJ_STEPS = 3
#: ``lambda_3 / lambda_2`` above which a matrix goes to ``numpy.linalg.eigh`` instead: after
#: :data:`ADJ_STEPS` products the others' share is then below ``GAP_MAX ** 3 = 1e-15``
GAP_MAX = 1e-5


def smallest_eigvec(c00, c01, c02, c11, c12, c22, start):
    """The unit eigenvector of the smallest eigenvalue of positive semi-definite symmetric 3 x 3 matrices.

    Parameters
    ----------
    c00, c01, c02, c11, c12, c22 : (h,) float, the entries
    start : (3,) float, a start vector, not orthogonal to the sought eigenvector (a plane fit: the
        axis the points are seen along)

    Returns
    -------
    (h, 3) float, unit (sign arbitrary, as an SVD's); NaN where an entry is not finite

    Inverse iteration by the adjugate ``adj C = det(C) C^-1`` (defined where ``C`` is singular: a
    rank-2 ``C`` has ``adj C`` along the null vector): :data:`ADJ_STEPS` products. A matrix whose
    two smallest eigenvalues are within :data:`GAP_MAX` of each other is solved by
    ``numpy.linalg.eigh`` (near-degenerate: the answer is ill-conditioned whoever computes it).
    """
    a00 = c11 * c22 - c12 * c12
    a01 = c02 * c12 - c01 * c22
    a02 = c01 * c12 - c02 * c11
    a11 = c00 * c22 - c02 * c02
    a12 = c01 * c02 - c00 * c12
    a22 = c00 * c11 - c01 * c01
    with np.errstate(invalid="ignore", divide="ignore"):  # a zero or non-finite matrix: NaN, then eigh or NaN
        vx = a00 * start[0] + a01 * start[1] + a02 * start[2]
        vy = a01 * start[0] + a11 * start[1] + a12 * start[2]
        vz = a02 * start[0] + a12 * start[1] + a22 * start[2]
        for _ in range(ADJ_STEPS - 1):
            f = 1.0 / np.sqrt(vx * vx + vy * vy + vz * vz)  # keeps the products in range
            vx, vy, vz = vx * f, vy * f, vz * f
            vx, vy, vz = (a00 * vx + a01 * vy + a02 * vz, a01 * vx + a11 * vy + a12 * vz,
                          a02 * vx + a12 * vy + a22 * vz)
        f = 1.0 / np.sqrt(vx * vx + vy * vy + vz * vz)
        v = np.stack([vx * f, vy * f, vz * f], axis=1)
        # lambda_3 (Rayleigh quotient), lambda_1 + lambda_2 and lambda_1 lambda_2 from the invariants
        l3 = ((c00 * v[:, 0] + 2.0 * (c01 * v[:, 1] + c02 * v[:, 2])) * v[:, 0]
              + (c11 * v[:, 1] + 2.0 * c12 * v[:, 2]) * v[:, 1] + c22 * v[:, 2] * v[:, 2])
        s12 = c00 + c11 + c22 - l3
        p12 = a00 + a11 + a22 - l3 * s12
        # lambda_2 >= p12 / s12: the gap test errs toward eigh
        close = ~(l3 * s12 <= GAP_MAX * p12)
    finite = np.isfinite(c00) & np.isfinite(c01) & np.isfinite(c02) & np.isfinite(c11) & np.isfinite(c12) & np.isfinite(c22)
    redo = np.flatnonzero(close & finite)
    if redo.size:
        C = np.empty((redo.size, 3, 3))
        C[:, 0, 0], C[:, 1, 1], C[:, 2, 2] = c00[redo], c11[redo], c22[redo]
        C[:, 0, 1] = C[:, 1, 0] = c01[redo]
        C[:, 0, 2] = C[:, 2, 0] = c02[redo]
        C[:, 1, 2] = C[:, 2, 1] = c12[redo]
        v[redo] = np.linalg.eigh(C)[1][:, :, 0]
    v[~finite] = np.nan
    return v


def inv3(a00, a01, a02, a11, a12, a22):
    """The inverse of symmetric 3 x 3 matrices given by their 6 entries (arrays): 6 arrays (NaN where singular)."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    det = a00 * c00 + a01 * c01 + a02 * c02
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(np.abs(det) > 1e-300, 1.0 / det, np.nan)
    return (c00 * f, c01 * f, c02 * f, (a00 * a22 - a02 * a02) * f, (a01 * a02 - a00 * a12) * f,
            (a00 * a11 - a01 * a01) * f)


def turned_tangent(K, mx, my, mz, sg):
    """:func:`turned` of shape operators tangent to the TCS ``xy`` plane, given by their entries
    ``K = (00, 01, 11)`` ((h,) arrays; the ``z`` row and column are 0): the 6 entries of ``Q K Q^T``."""
    k00, k01, k11 = K
    vx, vy = -sg * my, sg * mx  # sg e_z x m
    f = 1.0 / (1.0 + sg * mz)
    fx, fy = f * vx, f * vy
    # the first two columns of Q = I + [v]x + f [v]x^2, v = (vx, vy, 0)
    q00, q01 = 1.0 - fy * vy, fx * vy
    q11 = 1.0 - fx * vx
    q20, q21 = -vy, vx
    a00, a01 = q00 * k00 + q01 * k01, q00 * k01 + q01 * k11  # (Q K)_i0, (Q K)_i1
    a10, a11 = q01 * k00 + q11 * k01, q01 * k01 + q11 * k11
    a20, a21 = q20 * k00 + q21 * k01, q20 * k01 + q21 * k11
    return (a00 * q00 + a01 * q01, a00 * q01 + a01 * q11, a00 * q20 + a01 * q21, a10 * q01 + a11 * q11,
            a10 * q20 + a11 * q21, a20 * q20 + a21 * q21)


def smallest_rotation(kx, ky, kz, c):
    """The entries ``q[i][j]`` ((h,) arrays or floats) of the smallest rotation taking a unit ``v``
    onto a unit ``w``, given ``k = v x w`` and ``c = v . w`` (Rodrigues: ``I + [k]x + [k]x^2 / (1 + c)``,
    ``[k]x^2 = k k^T - |k|^2 I``; ``v`` and ``w`` not opposite)."""
    f = 1.0 / (1.0 + c)
    fx, fy, fz = f * kx, f * ky, f * kz
    xx, yy, zz = fx * kx, fy * ky, fz * kz
    xy, xz, yz = fx * ky, fx * kz, fy * kz
    return [[1.0 - yy - zz, xy - kz, xz + ky], [xy + kz, 1.0 - xx - zz, yz - kx], [xz - ky, yz + kx, 1.0 - xx - yy]]


def turned(K, mx, my, mz, sg):
    """The 6 entries ``(00, 01, 02, 11, 12, 22)`` ((h,) arrays) of ``Q K Q^T``, ``Q`` the smallest
    rotation taking ``sg e_z`` onto the unit normal ``m = (mx, my, mz)`` (arrays (h,), ``sg mz > 0``);
    ``K`` the 6 entries of symmetric 3 x 3 matrices: the shape operator given square to the drill
    axis (as for a head square to the panel) turned onto the fitted tangent plane. A projection
    ``T K T`` instead shrinks the curvature across the tilt by ``cos^2`` of it (0.8 % at 5 deg: on a
    3-sensor ring, whose curvature correction is of the order of 1 deg, about 0.01 deg of error)."""
    k00, k01, k02, k11, k12, k22 = K
    q = smallest_rotation(-sg * my, sg * mx, 0.0, sg * mz)  # k = sg e_z x m
    (q00, q01, q02), (q10, q11, q12), (q20, q21, q22) = q
    a = [[q00 * k00 + q01 * k01 + q02 * k02, q00 * k01 + q01 * k11 + q02 * k12, q00 * k02 + q01 * k12 + q02 * k22],
         [q10 * k00 + q11 * k01 + q12 * k02, q10 * k01 + q11 * k11 + q12 * k12, q10 * k02 + q11 * k12 + q12 * k22],
         [q20 * k00 + q21 * k01 + q22 * k02, q20 * k01 + q21 * k11 + q22 * k12, q20 * k02 + q21 * k12 + q22 * k22]]

    def e(i, j):  # (Q K Q^T)_ij = sum_l (Q K)_il Q_jl
        return a[i][0] * q[j][0] + a[i][1] * q[j][1] + a[i][2] * q[j][2]

    return e(0, 0), e(0, 1), e(0, 2), e(1, 1), e(1, 2), e(2, 2)


def full(k):
    """(h, 3, 3) from the 6 entries ``(00, 01, 02, 11, 12, 22)``."""
    k00, k01, k02, k11, k12, k22 = k
    out = np.empty(np.broadcast_shapes(*(np.shape(x) for x in k)) + (3, 3))
    out[..., 0, 0], out[..., 1, 1], out[..., 2, 2] = k00, k11, k22
    out[..., 0, 1] = out[..., 1, 0] = k01
    out[..., 0, 2] = out[..., 2, 0] = k02
    out[..., 1, 2] = out[..., 2, 1] = k12
    return out


def null_vector_cols(a, b, c):
    """(h, 4) unit vectors orthogonal to the columns ``a, b, c`` (each (4, h)) of a 4 x 3 matrix:
    the signed 3 x 3 minors of the rows left after dropping each one."""
    def det(i, j, k):
        return (a[i] * (b[j] * c[k] - b[k] * c[j]) - b[i] * (a[j] * c[k] - a[k] * c[j])
                + c[i] * (a[j] * b[k] - a[k] * b[j]))

    q = np.stack([det(1, 2, 3), -det(0, 2, 3), det(0, 1, 3), -det(0, 1, 2)])
    return (q / np.sqrt((q * q).sum(0))).T  # a view of (4, h): its transpose contiguous

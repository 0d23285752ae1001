"""Symmetric 3 x 3 matrices over arrays of holes, in closed form: each matrix given by its 6
entries ``(00, 01, 02, 11, 12, 22)`` as ``(h,)`` arrays (long inner loops, no per-hole LAPACK call)."""

from __future__ import annotations

import numpy as np

__all__ = ["smallest_eigvec", "ADJ_STEPS", "GAP_MAX"]

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

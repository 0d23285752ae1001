"""Symmetric 2 x 2 matrices over arrays of holes, in closed form: each matrix given by its entries
``(00, 01, 11)`` as ``(h,)`` arrays. Their eigenvalues, and the norms the measurement's curvature
bounds take of them (a tilt's covariance, a panel's curvature, the spots' second moments)."""

from __future__ import annotations

import numpy as np

__all__ = ["eig2", "nuclear2", "one_sign2"]


def eig2(a00, a01, a11):
    """``(l1, l2)``, ``l1 >= l2``: the eigenvalues of the symmetric 2 x 2 matrices ``[[a00, a01], [a01, a11]]``
    (arrays of one shape), ``(a00 + a11) / 2 +- sqrt((a00 - a11)^2 / 4 + a01^2)``."""
    disc = np.sqrt(0.25 * (a00 - a11) ** 2 + a01 * a01)
    mean = 0.5 * (a00 + a11)
    return mean + disc, mean - disc


def nuclear2(a00, a01, a11):
    """The nuclear norm ``|l1| + |l2|`` of symmetric 2 x 2 matrices (arrays)."""
    l1, l2 = eig2(a00, a01, a11)
    return np.abs(l1) + np.abs(l2)


def one_sign2(a00, a01, a11):
    """``max(sum of the positive, -sum of the negative eigenvalues)`` of symmetric 2 x 2 matrices ``M``
    (arrays): the largest ``|tr(K M)|`` over positive (or negative) semidefinite ``K`` of eigenvalues
    within 1 (a panel that curves one way, any orientation)."""
    l1, l2 = eig2(a00, a01, a11)
    return np.maximum(np.maximum(l1, 0) + np.maximum(l2, 0), -(np.minimum(l1, 0) + np.minimum(l2, 0)))

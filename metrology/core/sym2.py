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


def _mean_disc(a00, a01, a11):
    """``(|mean|, disc)``: the eigenvalues are ``mean +- disc`` (:func:`eig2`)."""
    return np.abs(0.5 * (a00 + a11)), np.sqrt(0.25 * (a00 - a11) ** 2 + a01 * a01)


def nuclear2(a00, a01, a11):
    """The nuclear norm ``|l1| + |l2|`` of symmetric 2 x 2 matrices (arrays): ``2 max(|mean|, disc)`` (one sign:
    ``|l1 + l2|``; two: ``l1 - l2``), without the eigenvalues."""
    m, disc = _mean_disc(a00, a01, a11)
    return 2.0 * np.maximum(m, disc)


def one_sign2(a00, a01, a11):
    """``max(sum of the positive, -sum of the negative eigenvalues)`` of symmetric 2 x 2 matrices ``M``
    (arrays): the largest ``|tr(K M)|`` over positive (or negative) semidefinite ``K`` of eigenvalues
    within 1 (a panel that curves one way, any orientation). ``|mean| + max(|mean|, disc)``: ``|l1 + l2|``
    where both have one sign (``disc <= |mean|``), else ``max(l1, -l2) = |mean| + disc``."""
    m, disc = _mean_disc(a00, a01, a11)
    return m + np.maximum(m, disc)

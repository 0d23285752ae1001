"""The closed-form smallest eigenvector of symmetric 3 x 3 matrices against numpy.linalg."""

from __future__ import annotations

import numpy as np

from metrology.core.sym3 import smallest_eigvec


def _entries(C):
    return tuple(np.ascontiguousarray(C[:, i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))


def _angle(v, w):
    """(h,) rad between unit vectors up to sign (an eigenvector's sign is arbitrary): asin |v x w|
    (not acos of the dot product, which is blind below 1e-8 rad)."""
    return np.arcsin(np.clip(np.linalg.norm(np.cross(v, w), axis=1), 0.0, 1.0))


def _scatter(rng, h, n, noise, spread=10.0, tilt=0.1):
    """The scatter of n points near tilted planes (a plane fit's), and the planes' normals."""
    xy = rng.normal(0.0, spread, (h, n, 2))
    g = rng.normal(0.0, tilt, (h, 2))
    z = (xy * g[:, None, :]).sum(2) + rng.normal(0.0, noise, (h, n))
    p = np.concatenate([xy, z[..., None]], axis=2)
    p = p - p.mean(1, keepdims=True)
    return np.einsum("hni,hnj->hij", p, p)


def test_random_plane_scatters_match_svd_and_eigh():
    rng = np.random.default_rng(3)
    for noise in (0.0, 1e-4, 1e-3, 0.05):
        C = _scatter(rng, 2000, 4, noise)
        v = smallest_eigvec(*_entries(C), np.array([0.0, 0.0, 1.0]))
        w = np.linalg.eigh(C)[1][:, :, 0]
        assert np.allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-15)
        assert _angle(v, w).max() < 1e-12, noise


def test_general_random_matrices_and_any_start():
    rng = np.random.default_rng(4)
    A = rng.normal(size=(3000, 3, 3))
    C = A @ A.transpose(0, 2, 1)
    start = np.array([0.3, -0.5, 0.8])
    v = smallest_eigvec(*_entries(C), start)
    lam, vec = np.linalg.eigh(C)
    w = vec[:, :, 0]
    # accuracy of any method: eps times the condition of the eigenvector, lambda_max / gap
    bound = 1e-13 * lam[:, 2] / (lam[:, 1] - lam[:, 0])
    assert np.all(_angle(v, w) <= np.maximum(bound, 1e-13))


def test_near_degenerate_and_singular():
    rng = np.random.default_rng(5)
    # exactly coplanar points (rank 2): the null vector exactly
    C = _scatter(rng, 500, 4, 0.0, tilt=0.0)
    v = smallest_eigvec(*_entries(C), np.array([0.0, 0.0, 1.0]))
    assert np.abs(np.abs(v[:, 2]) - 1.0).max() < 1e-15
    # the two smallest eigenvalues nearly equal (collinear points): the eigh fallback, still an eigenvector
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    C = 100.0 * d[:, :, None] * d[:, None, :] + np.eye(3) * 1e-3 + 1e-9 * np.diag([1.0, 2.0, 3.0])
    v = smallest_eigvec(*_entries(C), np.array([0.0, 0.0, 1.0]))
    lam = np.linalg.eigvalsh(C)[:, 0]
    r = np.einsum("hij,hj->hi", C, v) - lam[:, None] * v
    assert np.all(np.linalg.norm(r, axis=1) < 1e-12 * 100.0)
    assert np.allclose(np.linalg.norm(v, axis=1), 1.0)
    # a start orthogonal to the answer: found anyway
    C = np.broadcast_to(np.diag([4.0, 2.0, 1e-6]), (3, 3, 3)).copy()
    v = smallest_eigvec(*_entries(C), np.array([1.0, 0.0, 0.0]))
    assert np.allclose(np.abs(v), [0.0, 0.0, 1.0])
    # zero and non-finite matrices
    C = np.zeros((2, 3, 3))
    C[1, 0, 0] = np.nan
    v = smallest_eigvec(*_entries(C), np.array([0.0, 0.0, 1.0]))
    assert np.allclose(np.linalg.norm(v[0]), 1.0) and np.all(np.isnan(v[1]))

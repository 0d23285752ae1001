"""The fit's fast paths against their plain forms: the tangent shape's turn, the commanded pose's
turn, and surface_normal in slices against one call."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from metrology.io.layout import load_layout
from metrology.measure.panel import HoleSurfaces
from metrology.measure.surface import SLICE_ROWS, _full, _turned, _turned_tangent, fit_surface, surface_normal


ROOT = Path(__file__).resolve().parents[2]


def _tangent_shapes(rng, h):
    k = rng.normal(0.0, 1e-3, (h, 3))
    K = np.zeros((h, 3, 3))
    K[:, 0, 0], K[:, 0, 1], K[:, 1, 0], K[:, 1, 1] = k[:, 0], k[:, 1], k[:, 1], k[:, 2]
    return K


def test_the_tangent_turn_is_the_general_turn_of_a_shape_square_to_the_axis():
    rng = np.random.default_rng(7)
    h = 5000
    K = _tangent_shapes(rng, h)
    for sg in (1.0, -1.0):
        g = rng.normal(0.0, 0.1, (h, 2))
        rho = np.sqrt(1.0 + (g * g).sum(1))
        m = (-sg * g[:, 0] / rho, -sg * g[:, 1] / rho, sg / rho)
        six = tuple(K[:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
        a = _full(_turned(six, *m, sg))
        b = _full(_turned_tangent((K[:, 0, 0], K[:, 0, 1], K[:, 1, 1]), *m, sg))
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-18)
        # turned onto the tilted plane: null along its normal
        mm = np.stack(m, axis=1)
        np.testing.assert_allclose(np.einsum("hij,hj->hi", b, mm), 0.0, atol=1e-18)


def test_the_commanded_pose_turn_matches_the_matrix_products():
    rng = np.random.default_rng(8)
    m = 40
    n = rng.normal(0.0, 0.2, (m, 3)) + [0.0, 0.0, 1.0]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    S = rng.normal(0.0, 1e-3, (m, 3, 3))
    S = S + S.transpose(0, 2, 1)
    hs = HoleSurfaces(tuple(str(i) for i in range(m)), n, S, np.zeros((m, 2)), np.zeros(m), np.full(m, ""), "test")
    rows = rng.integers(0, m, 3000)
    R = Rotation.from_rotvec(rng.normal(0.0, 0.1, (3000, 3))).as_matrix()
    for s in (1.0, -1.0):
        got = hs.shape_pose(rows, R, s)
        K = np.einsum("hji,hjk,hkl->hil", R, S[rows], R)
        nt = np.einsum("hji,hj->hi", R, n[rows])
        ok = -s * nt[:, 2] > 1e-6
        six = tuple(K[ok][:, i, j] for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
        K[ok] = _full(_turned(six, -nt[ok, 0], -nt[ok, 1], nt[ok, 2], -s))
        assert ok.all() if s < 0 else not ok.any()  # the CAD's normal toward -s e_z: turned; away: kept
        np.testing.assert_allclose(got, K, rtol=0, atol=1e-17)


def test_surface_normal_in_slices_is_one_call_bit_for_bit():
    lay = load_layout(ROOT / "metrology" / "data" / "measured" / "nominal.toml")
    rng = np.random.default_rng(9)
    h = SLICE_ROWS * 2 + 123
    d = lay.range_mm.mean(1)[None] + rng.normal(0.0, 0.5, (h, lay.n))
    d[5, 1] = np.nan  # a blank: 3 readings
    d[7, :2] = np.nan  # 2: not ok
    K = _tangent_shapes(rng, h)
    normal, ok = surface_normal(lay, d, K)
    whole = fit_surface(lay, d, K, full=False)
    np.testing.assert_array_equal(ok, whole.ok)
    np.testing.assert_array_equal(normal, whole.normal)
    assert ok[5] and not ok[7] and np.all(np.isnan(normal[7]))
    one, good = surface_normal(lay, d[3], K[3])
    np.testing.assert_array_equal(one, normal[3])
    assert good

"""The fit's fast paths against their plain forms: the tangent shape's turn, the commanded pose's
turn, and surface_normal in slices against one call."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from metrology.core.sym3 import full as _full, turned as _turned, turned_tangent as _turned_tangent
from metrology.io.layout import load_layout
from metrology.measure.panel import HoleSurfaces
from metrology.measure.surface import SLICE_ROWS, fit_surface, surface_normal


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


def _old_smallest(v, w):
    """The smallest rotations taking unit v onto unit w as the matrix products (Rodrigues)."""
    k = np.cross(v, w)
    c = (v * w).sum(1)
    Kx = np.zeros((len(v), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    return np.eye(3)[None] + Kx + Kx @ Kx / (1.0 + c)[:, None, None]


def _old_convention_spin(Rc, m, s):
    """convention_spin's products as written first: Y = Q_m^T R^T Q(-e_z -> a) F F Q(-e_z -> f)^T R_c Q_m."""
    ez = np.broadcast_to(np.array([0.0, 0.0, -s]), m.shape)
    Qm = _old_smallest(ez, m)
    R = Rc @ np.swapaxes(Qm, 1, 2)
    a, f = R[:, :, 2] * s, Rc[:, :, 2] * s
    flip = np.array([1.0, -s, -s])
    down = np.broadcast_to(np.array([0.0, 0.0, -1.0]), m.shape)
    spin_c = np.swapaxes(_old_smallest(down, f) * flip, 1, 2) @ Rc
    X = np.swapaxes(R, 1, 2) @ (_old_smallest(down, a) * flip) @ spin_c
    return np.swapaxes(Qm, 1, 2) @ X @ Qm


def _plain_commanded_turn(Rc, m, nt, s):
    """commanded_turn's products (metrology/measure/commanded.py): the head ``R_c Q(m -> n_t)`` kept at the
    commanded spin in the cell's convention at its axis, ``Z = R_c^T R``, and ``Y = Q(n_t -> sg e_z) Z Q_m``."""
    sg = np.broadcast_to(np.array([0.0, 0.0, -s]), m.shape)
    R = Rc @ _old_smallest(m, nt)
    a, f = R[:, :, 2] * s, Rc[:, :, 2] * s
    flip = np.array([1.0, -s, -s])
    down = np.broadcast_to(np.array([0.0, 0.0, -1.0]), m.shape)
    spin_c = np.swapaxes(_old_smallest(down, f) * flip, 1, 2) @ Rc
    Z = np.swapaxes(Rc, 1, 2) @ (_old_smallest(down, a) * flip) @ spin_c
    return _old_smallest(nt, sg) @ Z @ _old_smallest(sg, m)


def _poses_and_normals(rng, h, s):
    """Commanded poses (the cell's convention at CAD normals up to 30 deg off the panel's z, spun and
    tilted a little) and measured normals a few degrees off the drill axis."""
    from metrology.measure.panel import tcs2panel_nominal

    n = rng.normal(0.0, 0.3, (h, 3)) + [0.0, 0.0, 1.0]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    Rc = tcs2panel_nominal(n, s) @ Rotation.from_rotvec(rng.normal(0.0, [0.02, 0.02, 0.5], (h, 3))).as_matrix()
    g = rng.normal(0.0, 0.05, (h, 2))
    m = s * np.column_stack([g, -np.ones(h)])  # toward the head: -s e_z tilted
    return Rc, m / np.linalg.norm(m, axis=1, keepdims=True)


def test_the_spin_convention_in_closed_form_is_the_matrix_products():
    from tests.measure.test_commanded import convention_spin  # the convention's closed form, now a reference

    rng = np.random.default_rng(10)
    for s in (1.0, -1.0):
        Rc, m = _poses_and_normals(rng, 4000, s)
        Y = convention_spin(Rc, m, s)
        np.testing.assert_allclose(Y, _old_convention_spin(Rc, m, s), rtol=0, atol=2e-15)
        np.testing.assert_allclose(Y @ np.swapaxes(Y, 1, 2), np.broadcast_to(np.eye(3), Y.shape), atol=2e-15)


def test_beyond_turns_the_shape_and_axes_and_corrects_the_readings_as_the_plain_formulas():
    """beyond_second_order's entries against the matrix products (Y^T K Y's tangent block, Y^T a) and
    the CAD's heights at the spots hole by hole with powers (second_order_readings' docstring)."""
    from metrology.measure.beyond import Beyond, beyond_second_order

    lay = load_layout(ROOT / "metrology" / "data" / "measured" / "nominal.toml")
    rng = np.random.default_rng(11)
    h = 300
    from metrology.measure.normals import drill_axis

    sa = drill_axis(lay)[2]
    Rc, _ = _poses_and_normals(rng, h, sa)
    d = lay.range_mm.mean(1)[None] + rng.normal(0.0, 1.0, (h, lay.n))
    K = _tangent_shapes(rng, h)
    # the local axes tangent at the CAD's normal, which the commanded pose holds 0.02 rad off its axis
    nt = rng.normal(0.0, 0.03, (h, 3)) + [0.0, 0.0, -sa]
    nt /= np.linalg.norm(nt, axis=1, keepdims=True)
    axes = rng.normal(size=(h, 2, 3))
    axes[:, 0] -= np.einsum("hi,hi->h", axes[:, 0], nt)[:, None] * nt
    axes[:, 0] /= np.linalg.norm(axes[:, 0], axis=1, keepdims=True)
    axes[:, 1] = np.cross(nt, axes[:, 0])
    higher = rng.normal(0.0, 1e-5, (h, 9))
    fit0 = fit_surface(lay, d, K, full=False)
    Yr = _plain_commanded_turn(Rc, fit0.normal, nt, sa)
    for terms in (Beyond(axes, higher, Rc), Beyond(axes, higher, None, Yr)):
        d2, kt, Y = beyond_second_order(lay, d, K, terms, fit0)
        np.testing.assert_allclose(Y, Yr, rtol=0, atol=2e-15)
        KY = np.swapaxes(Yr, 1, 2) @ K @ Yr
        for e, (i, j) in zip(kt, ((0, 0), (0, 1), (1, 1))):
            np.testing.assert_allclose(e, KY[:, i, j], rtol=0, atol=1e-17)
        ax = np.einsum("hji,hkj->hki", Yr, axes)
        for i in range(h):
            mi = fit0.normal[i]
            q = lay.zero + d[i, :, None] * lay.direction - [0.0, 0.0, fit0.c[i]]
            e = ax[i] - np.outer(ax[i] @ mi, mi)
            e /= np.linalg.norm(e, axis=1, keepdims=True)
            st = q @ e.T
            S, T = st[:, 0], st[:, 1]
            mono = [S ** 3 / 6, S ** 2 * T / 2, S * T ** 2 / 2, T ** 3 / 6, S ** 4 / 24, S ** 3 * T / 6,
                    S ** 2 * T ** 2 / 4, S * T ** 3 / 6, T ** 4 / 24]
            w = sum(c * x for c, x in zip(higher[i], mono))
            np.testing.assert_allclose(d2[i], d[i] + w / np.abs(lay.direction @ mi), rtol=0, atol=1e-13)


def test_the_fit_without_its_uncertainty_gives_the_same_pose_and_takes_the_shape_by_entries():
    lay = load_layout(ROOT / "metrology" / "data" / "measured" / "nominal.toml")
    rng = np.random.default_rng(12)
    h = 2000
    d = lay.range_mm.mean(1)[None] + rng.normal(0.0, 0.5, (h, lay.n))
    d[3, 2] = np.nan
    K = _tangent_shapes(rng, h)
    for steps in (1, 2, 3):
        a = fit_surface(lay, d, K, steps=steps)
        b = fit_surface(lay, d, K, steps=steps, full=False)
        c = fit_surface(lay, d, (K[:, 0, 0], K[:, 0, 1], K[:, 1, 1]), steps=steps)
        for x in (b, c):
            np.testing.assert_array_equal(x.normal, a.normal)
            np.testing.assert_array_equal(x.g, a.g)
            np.testing.assert_array_equal(x.c, a.c)
            np.testing.assert_array_equal(x.ok, a.ok)
        np.testing.assert_array_equal(c.A, a.A)

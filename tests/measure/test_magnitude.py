"""U95 of an angle that is the length of a 2-D tilt (metrology.measure.magnitude): the table
against scipy's Rice distribution and its own integral, and coverage of the true angle after the
cell's adjustment on holes the forward simulator drills."""

from __future__ import annotations

import functools
import numpy as np
import pytest

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.measure import magnitude as M
from metrology.measure.normals import K95, K95_2D
from metrology.measure.surface import surface_hole_normals
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_spec import LogSpec
from metrology.sim.forward.panels import make_panel
from tests.measure.helpers import ring_layout

TABLE6 = data_path("measured", "nominal.toml")


def _rice_q95(nu):
    """Isotropic, sigma 1: q with P(|R - nu| <= q) = 0.95, R ~ Rice(nu, 1), from scipy.stats.rice."""
    from scipy import optimize, stats

    return optimize.brentq(lambda q: stats.rice.cdf(nu + q, nu) - stats.rice.cdf(max(nu - q, 0.0), nu) - 0.95,
                           1e-6, 10.0)


def _rotated(x, r, w_dir, theta, sigma=3e-4):
    """g (1, 2), C (1, 2, 2) rad: major-axis sd ``sigma``, ratio ``r``, g at angle ``w_dir`` from the major axis."""
    v, u = np.array([np.cos(theta), np.sin(theta)]), np.array([-np.sin(theta), np.cos(theta)])
    C = sigma ** 2 * (np.outer(v, v) + r * np.outer(u, u))
    g = sigma * x * (np.cos(w_dir) * v + np.sin(w_dir) * u)
    return g[None], C[None]


@pytest.mark.parametrize("nu", [0.0, 0.7, 1.5, 3.0, 7.0, 15.0])
def test_isotropic_u95_is_the_rice_half_width(nu):
    g, C = _rotated(nu, 1.0, 0.3, 1.1)
    assert M.magnitude_u95(g, C)[0] / 3e-4 == pytest.approx(_rice_q95(nu), rel=2e-3)


def test_limits_and_the_linear_rule_far_out():
    g, C = _rotated(0.0, 1.0, 0.0, 0.0)
    assert M.magnitude_u95(g, C)[0] / 3e-4 == pytest.approx(K95_2D, rel=1e-3)  # at 0: the 2-D radius
    g, C = _rotated(0.0, 0.0, 0.0, 0.4)
    assert M.magnitude_u95(g, C)[0] / 3e-4 == pytest.approx(K95, rel=1e-3)  # a line through 0
    for r, w in ((0.3, 0.0), (0.3, 1.2), (1.0, 0.5)):  # far out: K95 times the sd along g, both sides of X_MAX
        for x in (M.X_MAX - 0.5, M.X_MAX + 5.0):
            g, C = _rotated(x, r, w, 2.0)
            radial = np.sqrt(np.cos(w) ** 2 + r * np.sin(w) ** 2)
            assert M.magnitude_u95(g, C)[0] / 3e-4 == pytest.approx(K95 * radial, rel=0.02)
    # near 1.5 sigma the length is compressed: below the 1-D factor
    g, C = _rotated(1.5, 1.0, 0.0, 0.0)
    assert M.magnitude_u95(g, C)[0] / 3e-4 < 1.9
    assert np.isnan(M.magnitude_u95(np.array([[np.nan, 0.0]]), C))[0]


def test_the_shipped_table_is_its_integral():
    t = M._table()
    rng = np.random.default_rng(4)
    i = rng.integers(0, len(M.GRID_X), 12)
    j = rng.integers(0, len(M.GRID_S), 12)
    k = rng.integers(0, len(M.GRID_W), 12)
    s = M.GRID_S[j]
    q = M._solve(M.GRID_X[i], s * s, M._phi(s, M.GRID_W[k]))
    np.testing.assert_allclose(t[i, j, k], q, rtol=1e-9)


def test_the_table_is_interpolated_linearly_between_its_points():
    """The lookup (``scipy.ndimage`` on the grid's fractional indices) against scipy.interpolate's
    linear RegularGridInterpolator on the grid's own coordinates, at random points of every segment
    of the x grid (steps 1/8, 1/4 and 1) and on the grid's edges."""
    from scipy.interpolate import RegularGridInterpolator

    rng = np.random.default_rng(11)
    n = 20_000
    x, s, w = rng.uniform(0.0, M.GRID_X[-1], n), rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.0, n)
    x[:50], s[50:100], w[100:150] = M.GRID_X[-1], 1.0, 0.0
    ref = RegularGridInterpolator((M.GRID_X, M.GRID_S, M.GRID_W), M._table())(np.stack([x, s, w], axis=1))
    got = M._lookup(x, s, w)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


def test_anisotropic_u95_holds_95_percent_of_the_length_given_the_tilt():
    """Monte Carlo over t ~ N(g, C): the share of |t| within |g| +- U95 (the definition) on an
    elongated covariance, g at several directions and distances (off the grid's points)."""
    rng = np.random.default_rng(7)
    for x, r, w in ((0.6, 0.15, 0.4), (2.3, 0.05, 1.3), (5.5, 0.4, 0.9), (11.0, 0.02, 1.5)):
        g, C = _rotated(x, r, w, 0.7)
        U = M.magnitude_u95(g, C)[0]
        t = rng.multivariate_normal(g[0], C[0], size=200_000)
        share = np.mean(np.abs(np.hypot(t[:, 0], t[:, 1]) - np.hypot(*g[0])) <= U)
        assert share == pytest.approx(0.95, abs=0.005), (x, r, w, share)


@pytest.mark.parametrize("sigma,a", [(1.0, 0.0), (1.0, 1.0), (1.0, 3.0), (0.3, 2.0), (0.0, 1.0)])
def test_normal_plus_uniform_u95_holds_95_percent(sigma, a):
    rng = np.random.default_rng(3)
    q = M.normal_uniform_u95(np.array([sigma]), np.array([a]))[0]
    x = rng.normal(0.0, 1.0, 1_000_000) * sigma + rng.uniform(-a, a, 1_000_000)
    assert np.mean(np.abs(x) <= q) == pytest.approx(0.95, abs=0.002)
    if a == 0:
        assert q == pytest.approx(K95 * sigma, rel=1e-6)
    if sigma == 0:
        assert q == pytest.approx(0.95 * a, rel=1e-6)


@pytest.mark.parametrize("shape", ["arcsine", "edge"])
@pytest.mark.parametrize("sigma,a", [(1.0, 0.0), (1.0, 1.0), (1.0, 3.0), (0.3, 2.0), (0.05, 1.0)])
def test_normal_plus_spread_u95_holds_95_percent(shape, sigma, a):
    """arcsine: a sine between the bounds, its phase uniform; edge: any distribution within them, checked at its worst
    (at a bound) and on a uniform and an arcsine spread (at least 95 %)."""
    rng = np.random.default_rng(4)
    q = M.normal_spread_u95(np.array([sigma]), np.array([a]), shape)[0]
    x = rng.normal(0.0, 1.0, 1_000_000) * sigma
    sine = a * np.sin(rng.uniform(-0.5 * np.pi, 0.5 * np.pi, x.size))
    if shape == "arcsine":
        assert np.mean(np.abs(x + sine) <= q) == pytest.approx(0.95, abs=0.002)
    else:
        assert np.mean(np.abs(x + a) <= q) == pytest.approx(0.95, abs=0.002)
        assert np.mean(np.abs(x + sine) <= q) >= 0.948
        assert np.mean(np.abs(x + rng.uniform(-a, a, x.size)) <= q) >= 0.948
    if a == 0:
        assert q == pytest.approx(K95 * sigma, rel=1e-3)


def _adjusted(layout, kind="flat", R=None, n=6000, seed=5):
    """Holes the forward simulator drills and adjusts (its own micro-plane controller, the head's
    true layout as the cell's): the after-readings and the true angle after."""
    panel = make_panel(kind, R) if R else make_panel(kind)
    spec = LogSpec(layout, layout, panel, resolution_mm=0.0)
    ch = next(simulate_cell(spec, seed, 0, n, n))
    ok = np.all(np.isfinite(ch.d_after), axis=1) & ch.adjusted
    return ch, ok


@pytest.mark.parametrize("head", ["table6", "ring3"])
def test_u95_after_the_adjustment_covers_95_percent_of_the_true_angle(head):
    """After the adjustment the true angle is of the order of the reading noise's spread: the 2-D
    radius (the rule before) held 98 % of the true angles here, a 1-D factor under-covers."""
    lay = load_layout(TABLE6) if head == "table6" else ring_layout(3, radius=50.0, z0=-35.0, inclination_deg=30.0,
                                                                    noise=0.003)
    if head == "ring3":  # an elliptic ring: the tilt's covariance is elongated
        z = lay.zero * np.array([1.0, 0.8, 1.0])
        lay = lay.with_params(z, lay.direction, range_mm=np.tile([20.0, 90.0], (3, 1)))
    ch, ok = _adjusted(lay)
    h, _ = surface_hole_normals(lay, ch.d_after[ok], np.zeros((ok.sum(), 3, 3)))
    assert np.median(ch.true_after[ok]) < 4 * np.median(h.u_angle)  # the regime this is about
    cover = np.mean(np.abs(h.angle - ch.true_after[ok]) <= h.U95)
    assert 0.935 <= cover <= 0.965, cover
    # before the adjustment (0.5-5 deg, far from 0): the linear rule, unchanged
    hb, _ = surface_hole_normals(lay, ch.d[ok], np.zeros((ok.sum(), 3, 3)))
    assert np.mean(np.abs(hb.angle - ch.true_angle[ok]) <= hb.U95) == pytest.approx(0.95, abs=0.012)


@functools.lru_cache(maxsize=1)
def _spun_cell(holes=3000, seed=3):
    """A 3-sensor ring on a barrel R 500 (axis at 30 deg), the head's spin drawn within +-2 deg by the
    simulator; each hole's surface from the panel's mesh, spin stated +-2 deg. Simulated once for both logs
    (with and without the pose): the cell and the surfaces are most of the test's time."""
    from metrology.jobs.measure_panel import panel_hole_surfaces
    from metrology.measure.panel import HoleTable
    from metrology.panel.mesh import Panel
    from tests.measure.panel_fixtures import panel_mesh

    lay = ring_layout(3, radius=50.0, z0=-35.0, inclination_deg=30.0, noise=0.003)
    lay = lay.with_params(lay.zero, lay.direction, range_mm=np.tile([20.0, 90.0], (3, 1)))
    panel = make_panel("cylinder", 500.0, axis=(np.cos(0.5), np.sin(0.5), 0.0))
    spec = LogSpec(lay, lay, panel, resolution_mm=0.0, patch_half_mm=40.0, spin_rad=np.radians(2.0))
    ch = next(simulate_cell(spec, seed, 0, holes, holes))
    ids = tuple(f"h{i}" for i in range(holes))
    table = HoleTable(ids, ch.drill_point, -panel.normal_at(ch.drill_point), "holes.csv")
    surf = panel_hole_surfaces(Panel(panel_mesh(panel, half_mm=150.0, step_mm=3.0)), table, 55.0,
                               spin=np.radians(2.0))
    return lay, ch, surf, ids


def _spun_batch(with_pose):
    """The cell of :func:`_spun_cell` measured, its log with or without the commanded pose."""
    import pyarrow as pa

    from metrology.io.holelog_schema import CELL, PANEL, TIME_S
    from metrology.measure.holes import Settings, measure_batch

    lay, ch, surf, ids = _spun_cell()
    holes = len(ids)
    cols = {"hole_id": list(ids), CELL: ["C1"] * holes, PANEL: ["P1"] * holes,
            TIME_S: (1.8e9 + np.arange(holes)).astype(float)}
    for j, nm in enumerate(lay.names):
        cols[f"d_{nm}"] = ch.d[:, j]
    if with_pose:  # as metrology/sim/forward/log_write.py logs it; the first 100 rows without one
        for j, ax in enumerate("xyz"):
            cols[f"pose_r{ax}_deg"] = np.where(np.arange(holes) < 100, np.nan, np.degrees(ch.pose_rotvec[:, j]))
            cols[f"pose_{ax}_mm"] = np.where(np.arange(holes) < 100, np.nan, ch.pose_origin[:, j])
    b = measure_batch(lay, pa.table(cols), Settings(surfaces=surf))
    U = np.radians(b.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
    return b.angle_before, U, ch.true_angle


def test_with_the_commanded_pose_the_heads_spin_leaves_u95():
    """The spin doubt is real without the pose (leaving it out of U95 there covers far less than
    95 %); with the pose the spin is known: U95 shrinks to what the readings and the panel give and
    still covers 95 %; a row whose pose is blank keeps the spin term."""
    a0, U0, t0 = _spun_batch(False)
    a1, U1, t1 = _spun_batch(True)
    ok = np.isfinite(a0) & np.isfinite(a1)
    posed = ok & (np.arange(len(ok)) >= 100)
    cover0 = np.mean(np.abs(a0 - t0)[ok] <= U0[ok])
    cover1 = np.mean(np.abs(a1 - t1)[posed] <= U1[posed])
    # without the pose the spin's bound dominates U95, taken as any spin within it (measure.spin.SPIN_BOUND_MODEL):
    # it holds, and over-covers a spin the simulator draws uniformly per hole (99.4 % here; as a uniform 94.4 %, which
    # a spin drifting or held near the bound under-covers: docs/spin.md)
    assert 0.95 <= cover0 <= 0.997, cover0
    # with it: 93.7 % here (2900 holes, +-0.4 %; the same head unspun 94.5 %: the ring's 3 spots 50 mm
    # out on R 500 see the surface's 4th-order term, which the fit leaves out)
    assert 0.925 <= cover1 <= 0.965, cover1
    assert np.median(U1[posed]) < 0.7 * np.median(U0[ok])
    np.testing.assert_allclose(U1[:100], U0[:100], rtol=1e-9)  # no pose on the row: the cell's convention, spin in


@pytest.mark.parametrize("nu,lo,hi", [(0.0, 0.79, 0.85), (5.0, 0.94, 0.96)])
def test_coverage_against_a_fixed_true_angle(nu, lo, hi):
    """The rule's coverage of a fixed true length (isotropic, sigma 1): near 95 % a few sigma out,
    about 82 % at exactly 0 (the measured length is then always above it): the module docstring."""
    rng = np.random.default_rng(11)
    m = rng.standard_normal((200_000, 2)) + np.array([nu, 0.0])
    U = M.magnitude_u95(m, np.broadcast_to(np.eye(2), (len(m), 2, 2)))
    assert lo <= np.mean(np.abs(np.hypot(m[:, 0], m[:, 1]) - nu) <= U) <= hi

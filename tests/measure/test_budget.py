"""The budget (metrology.measure.budget): one combiner for both fitters."""

import numpy as np
import pytest

from metrology.measure.budget import (CALIBRATION, PANEL_SHAPE, READING_NOISE, SPIN, SPIN_READ, SURFACE_MODEL,
                                      Budget, Kind, Source, combine)
from metrology.measure.magnitude import K95, normal_spread_u95, normal_uniform_u95
from metrology.measure.normals import hole_normals
from metrology.measure.surface import surface_hole_normals
from tests.measure.helpers import calibrated_layout, cast_plane, standoff_point, tilted_normals


def _plane_readings(lay, n, angles, seed, noise=0.003):
    rng = np.random.default_rng(seed)
    p, axis = standoff_point(lay, 50.0, n)
    nrm, _ = tilted_normals(rng, n, *angles, axis=axis)
    return cast_plane(lay.zero, lay.direction, nrm, p) + rng.normal(0, noise, (n, lay.n))


def _head(name):
    """(the layout metro measures with, the true head) for ``name``: the paper's Table 6 and Table 2 heads (beams
    inclined 30 deg to the drill axis), a random 4-sensor and 3-sensor ring (forward.draw_head), Table 6's first
    three sensors. The measuring layout states a different noise per sensor and a block-diagonal calibration
    covariance different per sensor (zero and beam): weights that differ between the spots."""
    from metrology.core.layout import SensorLayout
    from metrology.core.paper import TABLE2_NOMINAL, TABLE6_NOMINAL, layout_from_table
    from metrology.sim.forward import draw_head, perturb_layout

    rng = np.random.default_rng(sum(map(ord, name)))  # one head per name, the same every run
    if name.startswith("ring"):
        nominal = draw_head(rng, int(name[4])).nominal
    else:
        nominal = layout_from_table(TABLE6_NOMINAL if name.startswith("table6") else TABLE2_NOMINAL)
        if name == "table2":  # beams -z: the frame turned 180 deg about x (benchmarks/study_measure.py)
            flip = np.diag([1.0, -1.0, -1.0])
            nominal = SensorLayout(nominal.names, nominal.zero @ flip, nominal.direction @ flip)
        if name.endswith("3"):
            nominal = nominal.subset(nominal.names[:3])
    n = nominal.n
    noise = 0.003 * (1.0 + np.arange(n))  # 3, 6, 9, 12 um
    sd = np.concatenate([[0.002 * (i + 1)] * 3 + [np.radians(0.005 * (n - i))] * 2 for i in range(n)])
    lay = SensorLayout(nominal.names, nominal.zero, nominal.direction, noise, np.tile([30.0, 70.0], (n, 1)),
                       covariance=np.diag(sd ** 2))
    true = perturb_layout(rng, lay)
    return lay, true.with_params(true.zero, true.direction, noise_mm=noise, range_mm=np.tile([30.0, 70.0], (n, 1)))


def _flat_holes(lay, true, holes=1500, seed=3):
    """Readings before and after the cell's adjustment (true angles 0.5-5 deg, then near 0) of holes on a flat
    panel, cast by the forward simulator; the holes with every reading."""
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.panels import make_panel

    ch = next(simulate_cell(LogSpec(true_layout=true, cell_layout=lay, panel=make_panel("flat"), spin_rad=np.pi),
                            seed, 0, holes, chunk_holes=holes))
    return [(d[np.all(np.isfinite(d), axis=1)], t[np.all(np.isfinite(d), axis=1)])
            for d, t in ((ch.d, ch.true_angle), (ch.d_after, ch.true_after))]


@pytest.mark.parametrize("head", ["table6", "table2", "ring4", "ring3", "table6 L1-L3"])
def test_a_flat_panel_through_the_panel_path_is_the_micro_plane_exactly(head):
    # one estimator (metrology.measure.estimator) and one budget: on a flat panel the panel path's angle, U95 and
    # every share are the micro-plane's to the last bit, 3 and 4 sensors, beams inclined to the drill axis,
    # a different noise and calibration per sensor; before the adjustment (the linear rule) and after (near 0:
    # the tilt's length)
    lay, true = _head(head)
    for d, _ in _flat_holes(lay, true):
        plane = hole_normals(lay, d, min_radius_mm=np.inf)
        surf, _ = surface_hole_normals(lay, d, np.zeros((len(d), 3, 3)))
        np.testing.assert_array_equal(surf.U95, plane.U95)
        np.testing.assert_array_equal(surf.angle, plane.angle)
        np.testing.assert_array_equal(surf.u_angle, plane.u_angle)
        np.testing.assert_array_equal(surf.u_angle_noise, plane.u_angle_noise)
        np.testing.assert_array_equal(surf.normal, plane.normal)
        np.testing.assert_array_equal(surf.budget.cov, plane.budget.cov)
        if lay.n == 4:
            np.testing.assert_array_equal(surf.residual, plane.residual)
        assert np.all(np.isfinite(plane.U95)) and np.all(plane.U95 > 0)


def test_the_estimator_weighs_a_noisy_sensor_down():
    # Gauss-Markov: a sensor 4x noisier than the others weighs 1/16 as much; on forward-simulated holes the
    # angle's RMS error is well below the unweighted micro-plane's (the plane through the spots, lstsq here)
    # and angle +- U95 still holds the true angle in ~95 % of holes
    lay, _ = _head("table6")
    noise = np.array([0.012, 0.003, 0.003, 0.003])
    lay = lay.with_params(lay.zero, lay.direction, noise_mm=noise, covariance=lay.covariance * 0.01)
    d, truth = _flat_holes(lay, lay, holes=3000, seed=5)[0]  # the head as calibrated: its noise alone
    h = hole_normals(lay, d, min_radius_mm=np.inf)
    S = lay.zero[None] + d[:, :, None] * lay.direction[None]  # (N, 4, 3) spots
    X = np.concatenate([np.ones(S.shape[:2] + (1,)), S[:, :, :2]], axis=2)
    g = np.stack([np.linalg.lstsq(X[i], S[i, :, 2], rcond=None)[0][1:] for i in range(len(d))])
    err_plain = np.arctan(np.hypot(g[:, 0], g[:, 1])) - truth
    err = h.angle - truth
    assert np.sqrt(np.mean(err ** 2)) < 0.85 * np.sqrt(np.mean(err_plain ** 2))
    assert 0.93 < np.mean(np.abs(err) <= h.U95) < 0.97


def test_both_fitters_return_one_budget_of_named_sources():
    lay = calibrated_layout()
    d = _plane_readings(lay, 500, (0.5, 5.0), seed=2)
    plane = hole_normals(lay, d)
    surf, _ = surface_hole_normals(lay, d, np.zeros((len(d), 3, 3)))
    assert plane.budget.names[:2] == (READING_NOISE, CALIBRATION)
    assert surf.budget.names == (READING_NOISE, CALIBRATION, PANEL_SHAPE, SPIN, SPIN_READ, SURFACE_MODEL)
    for h in (plane, surf):
        un = combine(h.budget)
        np.testing.assert_array_equal(un.U95, h.U95)
        np.testing.assert_array_equal(un.of(READING_NOISE), h.u_angle_noise)
        far = un.angle > 10 * un.u
        # away from 0 the shares add in quadrature to u
        np.testing.assert_allclose(np.sqrt((un.share[far] ** 2).sum(1)), un.u[far], rtol=1e-12)


def test_adding_a_source_is_one_entry():
    g = np.array([[0.01, 0.0], [0.0, 0.02], [1e-5, 0.0]])
    cov = np.tile([1e-8, 0.0, 1e-8], (3, 1))
    b = Budget(g, (Source(READING_NOISE, cov),))
    b2 = b.with_source(Source("layout effect terms", cov * 3.0))
    u1, u2 = combine(b), combine(b2)
    far = u1.angle > 100 * u1.u
    np.testing.assert_allclose(u2.u[far], 2.0 * u1.u[far], rtol=1e-12)  # 1 + 3 = 4 times the variance
    np.testing.assert_allclose(u2.of("layout effect terms")[far], np.sqrt(3.0) * u1.u[far], rtol=1e-12)
    np.testing.assert_allclose(u2.U95[far], K95 * u2.u[far], rtol=1e-12)
    assert not far[2]  # near 0 the length's half-width, not the linear rule
    assert u2.U95[2] > K95 * u2.u[2]
    with pytest.raises(ValueError, match="already"):
        b2.with_source(Source(READING_NOISE, cov))
    with pytest.raises(ValueError, match="shape"):
        b.with_source(Source("x", cov[:2]))
    assert Budget.concat([b2.rows(slice(0, 1)), b2.rows(slice(1, 3))]).names == b2.names


def test_a_uniform_source_takes_the_normal_plus_uniform_rule():
    g = np.array([[0.05, 0.0]])
    sd, a = 1e-4, 3e-4
    b = Budget(g, (Source(READING_NOISE, np.array([[sd ** 2 * (1 + 0.0025) ** 2, 0.0, 0.0]])),
                   Source(SPIN, np.zeros((1, 3)), Kind.UNIFORM, np.array([a]))))
    un = combine(b)
    assert un.u[0] == pytest.approx(np.hypot(sd, a / np.sqrt(3.0)), rel=1e-9)
    assert un.U95[0] == pytest.approx(normal_uniform_u95(np.array([sd]), np.array([a]))[0], rel=1e-9)


@pytest.mark.parametrize("kind,var", [(Kind.ARCSINE, 0.5), (Kind.EDGE, 1.0)])
def test_a_spread_source_takes_its_shape_s_rule(kind, var):
    g = np.array([[0.05, 0.0]])
    sd, a = 1e-4, 3e-4
    noise = Source(READING_NOISE, np.array([[sd ** 2 * (1 + 0.0025) ** 2, 0.0, 0.0]]))
    un = combine(Budget(g, (noise, Source(SPIN, np.zeros((1, 3)), kind, np.array([a])))))
    assert un.u[0] == pytest.approx(np.hypot(sd, a * np.sqrt(var)), rel=1e-9)
    assert un.U95[0] == pytest.approx(normal_spread_u95(np.array([sd]), np.array([a]), kind.value)[0], rel=1e-9)
    # beside a uniform one (the spin read) the wider shape takes both half-widths
    both = combine(Budget(g, (noise, Source(SPIN, np.zeros((1, 3)), kind, np.array([a])),
                              Source(SPIN_READ, np.zeros((1, 3)), Kind.UNIFORM, np.array([a])))))
    assert both.U95[0] == pytest.approx(normal_spread_u95(np.array([sd]), np.array([2 * a]), kind.value)[0], rel=1e-9)
    uniform = combine(Budget(g, (noise, Source(SPIN, np.zeros((1, 3)), Kind.UNIFORM, np.array([a])))))
    assert un.U95[0] > uniform.U95[0]


def test_engines_and_panel_sources_each_behind_one_protocol():
    import inspect

    from metrology.jobs.measure_panel import CadPanel
    from metrology.measure.fleet import DaskEngine
    from metrology.measure.panel import SurfaceSource, TableNormals
    from metrology.measure.run import Engine, OneProcess

    for cls in (OneProcess, DaskEngine):
        for name in ("plan", "pieces", "watches"):
            assert list(inspect.signature(getattr(cls, name)).parameters) == \
                list(inspect.signature(getattr(Engine, name)).parameters), (cls, name)
    for cls in (TableNormals, CadPanel):
        assert list(inspect.signature(cls.surfaces).parameters) == \
            list(inspect.signature(SurfaceSource.surfaces).parameters), cls


def test_a_budget_keeps_its_combination_and_a_new_source_drops_it():
    """The panel fit keeps what :func:`combine` made of its budget (the spin's share reads it again): the same bits
    as combining afresh, for the whole and for rows and halves joined; a budget with one more source is new."""
    lay = calibrated_layout()
    d = _plane_readings(lay, 600, (0.0, 5.0), seed=5)  # near 0 (the length's rule) and far from it
    K = np.zeros((len(d), 3, 3))
    K[:, 0, 0], K[:, 1, 1] = 1 / 500, -1 / 900
    parts = [surface_hole_normals(lay, d[s], K[s])[0].budget for s in (slice(0, 250), slice(250, 600))]
    whole = Budget.concat(parts)
    for b in (parts[0], whole, whole.rows(np.arange(100, 500, 3))):
        assert b.combined is not None and combine(b) is b.combined
        fresh = combine(Budget(b.tilt, b.sources))
        for f in ("angle", "u", "U95", "share"):
            np.testing.assert_array_equal(getattr(b.combined, f), getattr(fresh, f))
    widened = whole.with_source(Source("layout effect terms", np.full((len(whole), 3), 1e-8)))
    assert widened.combined is None
    assert not np.array_equal(combine(widened).u, whole.combined.u)  # combined afresh, with the new source

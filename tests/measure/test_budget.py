"""The budget (metrology.measure.budget): one combiner for both fitters."""

import numpy as np
import pytest

from metrology.measure.budget import (CALIBRATION, PANEL_SHAPE, READING_NOISE, SPIN, SURFACE_MODEL, Budget, Kind, Source,
                                      combine)
from metrology.measure.magnitude import K95, normal_uniform_u95
from metrology.measure.normals import hole_normals
from metrology.measure.surface import surface_hole_normals
from tests.measure.helpers import calibrated_layout, cast_plane, standoff_point, tilted_normals


def _plane_readings(lay, n, angles, seed, noise=0.003):
    rng = np.random.default_rng(seed)
    p, axis = standoff_point(lay, 50.0, n)
    nrm, _ = tilted_normals(rng, n, *angles, axis=axis)
    return cast_plane(lay.zero, lay.direction, nrm, p) + rng.normal(0, noise, (n, lay.n))


@pytest.mark.parametrize("angles", [(0.5, 5.0), (0.0, 0.05)])
def test_a_flat_panel_through_the_panel_path_gives_the_micro_planes_u95(angles):
    # 3 sensors: the fit is exact, the two estimators are one; the budgets are one: U95 equal (to rounding)
    lay = calibrated_layout().subset(("L1", "L2", "L3"))
    d = _plane_readings(lay, 3000, angles, seed=1)
    plane = hole_normals(lay, d, min_radius_mm=np.inf)
    surf, _ = surface_hole_normals(lay, d, np.zeros((len(d), 3, 3)))
    np.testing.assert_allclose(surf.U95, plane.U95, rtol=1e-12, atol=0)
    np.testing.assert_allclose(surf.u_angle, plane.u_angle, rtol=1e-12, atol=0)
    np.testing.assert_allclose(surf.u_angle_noise, plane.u_angle_noise, rtol=1e-12, atol=0)


def test_four_sensors_square_to_a_flat_panel_give_the_micro_planes_u95():
    # 4 sensors: the panel path weights each reading by its noise along the normal, equal when the head
    # is square to the panel (a symmetric head): then the same estimator and the same U95
    lay = calibrated_layout()
    p, axis = standoff_point(lay, 50.0, 5)
    d = cast_plane(lay.zero, lay.direction, np.tile(axis, (5, 1)) * -1.0, p)
    plane = hole_normals(lay, d, min_radius_mm=np.inf)
    surf, _ = surface_hole_normals(lay, d, np.zeros((len(d), 3, 3)))
    np.testing.assert_allclose(surf.U95, plane.U95, rtol=1e-9, atol=0)


def test_both_fitters_return_one_budget_of_named_sources():
    lay = calibrated_layout()
    d = _plane_readings(lay, 500, (0.5, 5.0), seed=2)
    plane = hole_normals(lay, d)
    surf, _ = surface_hole_normals(lay, d, np.zeros((len(d), 3, 3)))
    assert plane.budget.names[:2] == (READING_NOISE, CALIBRATION)
    assert surf.budget.names == (READING_NOISE, CALIBRATION, PANEL_SHAPE, SPIN, SURFACE_MODEL)
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

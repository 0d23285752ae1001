"""Beam casting against hand-computed distances and angles."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from metrology.sim.forward import DatumSurface, cast_beams, draw_surface, flat_surface


def _pose_over(surf, standoff, tilt_rad=0.0, tilt_axis=None, s=0.0, t=0.0):
    """TCS z along -normal, origin ``standoff`` mm above the reference plane at (s, t), tilted."""
    R0 = np.stack([surf.axis_s, -surf.axis_t, -surf.normal], axis=1)
    axis = surf.axis_s if tilt_axis is None else tilt_axis
    R = Rotation.from_rotvec(axis * tilt_rad).as_matrix() @ R0
    T = surf.origin + s * surf.axis_s + t * surf.axis_t + standoff * surf.normal
    return R[None], T[None]


def test_flat_datum_beam_along_the_normal():
    surf = flat_surface([300.0, -150.0, 1900.0], [0.1, 0.3, -1.0])
    R, T = _pose_over(surf, 37.5)
    hit = cast_beams(surf, [[0.0, 0.0, -12.5]], [[0.0, 0.0, 1.0]], R, T)
    assert hit.d[0, 0] == pytest.approx(50.0, abs=1e-9)
    assert hit.incidence[0, 0] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("beta_deg", [10.0, 25.0, 35.0])
def test_flat_datum_inclined_beam_is_h_over_cos(beta_deg):
    surf = flat_surface([-500.0, 800.0, 1500.0], [0.0, -0.2, -1.0])
    R, T = _pose_over(surf, 20.0)
    b = np.radians(beta_deg)
    u = [[np.sin(b), 0.0, np.cos(b)]]
    hit = cast_beams(surf, [[30.0, 0.0, -25.0]], u, R, T)
    assert hit.d[0, 0] == pytest.approx(45.0 / np.cos(b), abs=1e-9)
    assert hit.incidence[0, 0] == pytest.approx(b, abs=1e-12)


@pytest.mark.parametrize("tilt_deg", [3.0, 9.0, 14.0])
def test_incidence_on_a_flat_plane_equals_the_tilt(tilt_deg, rng):
    surf = flat_surface([0.0, 0.0, 2000.0], [0.0, 0.0, -1.0])
    axis = np.cross(surf.normal, rng.normal(size=3))
    axis /= np.linalg.norm(axis)
    R, T = _pose_over(surf, 40.0, np.radians(tilt_deg), axis)
    hit = cast_beams(surf, [[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], R, T)
    assert hit.incidence[0, 0] == pytest.approx(np.radians(tilt_deg), abs=1e-12)
    assert hit.d[0, 0] == pytest.approx(40.0 / np.cos(np.radians(tilt_deg)), abs=1e-9)


def test_quadratic_form_against_the_closed_form_root(rng):
    """Bow + twist make h quadratic in (s, t), so the residual is quadratic in d: solve it by hand."""
    surf = DatumSurface([100.0, 50.0, 2100.0], [0.05, -0.1, -1.0], [1.0, 0.0, 0.0], None, (400.0, 300.0),
                        0.8, 0.5, -0.3)
    Ls, Lt = surf.half_extent
    for _ in range(10):
        R, T = _pose_over(surf, rng.uniform(10, 40), np.radians(rng.uniform(0, 14)),
                          s=rng.uniform(-200, 200), t=rng.uniform(-150, 150))
        zero = rng.normal(size=(1, 3)) * 30 + [0, 0, -30]
        u = np.array([[0.3, -0.2, 1.0]]) / np.linalg.norm([0.3, -0.2, 1.0])
        a = R[0] @ zero[0] + T[0] - surf.origin
        b = R[0] @ u[0]
        s0, s1 = a @ surf.axis_s, b @ surf.axis_s
        t0, t1 = a @ surf.axis_t, b @ surf.axis_t
        w0, w1 = a @ surf.normal, b @ surf.normal
        ks, kt, kst = surf.bow_s / Ls**2, surf.bow_t / Lt**2, surf.twist / (Ls * Lt)
        # w0 + w1 d - [ks (s0 + s1 d)^2 + kt (t0 + t1 d)^2 + kst (s0 + s1 d)(t0 + t1 d)] = 0
        A = -(ks * s1**2 + kt * t1**2 + kst * s1 * t1)
        B = w1 - (2 * ks * s0 * s1 + 2 * kt * t0 * t1 + kst * (s0 * t1 + s1 * t0))
        C = w0 - (ks * s0**2 + kt * t0**2 + kst * s0 * t0)
        roots = np.roots([A, B, C])
        d_exact = min(r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0)
        hit = cast_beams(surf, zero, u, R, T)
        assert hit.d[0, 0] == pytest.approx(d_exact, abs=1e-9)


def test_cast_distance_lies_on_strongly_formed_surfaces(rng):
    for _ in range(5):
        surf, _ = draw_surface(rng, form_mm=5.0, shape="mixed")
        R, T = _pose_over(surf, 30.0, np.radians(10), s=50.0, t=-80.0)
        zero = np.array([[40.0, 0, -30], [-20, 35, -30], [-20, -35, -30]])
        u = np.array([[-0.4, 0, 1], [0.2, -0.35, 1], [0.2, 0.35, 1]])
        hit = cast_beams(surf, zero, u, R, T)
        s, t, w = surf.plane_coords(hit.spot[0])
        assert np.all(hit.valid)
        assert np.max(np.abs(w - surf.height(s, t))) < 1e-9


def test_bracketing_fallback_agrees_with_newton(rng):
    surf, _ = draw_surface(rng, form_mm=2.0, shape="mixed")
    R, T = _pose_over(surf, 25.0, np.radians(12), s=-40.0, t=60.0)
    zero = np.array([[40.0, 0, -30], [-20, 35, -30], [-20, -35, -30]])
    u = np.array([[-0.4, 0, 1], [0.2, -0.35, 1], [0.2, 0.35, 1]])
    newton = cast_beams(surf, zero, u, R, T)
    brent = cast_beams(surf, zero, u, R, T, max_newton=0)  # every beam through the fallback
    assert np.all(brent.valid)
    assert np.max(np.abs(brent.d - newton.d)) < 1e-9
    assert np.allclose(brent.incidence, newton.incidence, atol=1e-10)


def test_misses_are_nan():
    surf = flat_surface([0.0, 0.0, 2000.0], [0.0, 0.0, -1.0], half_extent=(100.0, 100.0))
    R, T = _pose_over(surf, 40.0)
    hit = cast_beams(surf, [[0, 0, 0], [0, 0, 0], [0, 0, 0]], [[0, 0, -1.0], [1.0, 0, 1e-3], [0, 0, 1.0]], R, T)
    assert not hit.valid[0, 0] and np.isnan(hit.d[0, 0])  # pointing away
    assert not hit.valid[0, 1] and np.isnan(hit.incidence[0, 1])  # lands far off the extent
    assert hit.valid[0, 2] and hit.d[0, 2] == pytest.approx(40.0, abs=1e-9)


def test_flat_datum_agrees_with_the_project_measurement_model(rng):
    """A second, independent implementation: the paper's Eqs. 1-3 in metrology.core.model."""
    from metrology.core.frames import plane_in_tcs
    from metrology.core.model import readings
    from metrology.sim.forward import draw_case

    for seed in rng.integers(0, 2**31, 5):
        case = draw_case(np.random.default_rng(seed), "none", noise_mm=0.003)
        surf = case.surface
        n_tcs, D_tcs = plane_in_tcs(surf.normal, -surf.normal @ surf.origin, case.true_rot, case.true_trans)
        d_model, valid = readings(case.true.zero, case.true.direction, n_tcs, D_tcs)
        assert np.all(valid)
        assert np.max(np.abs(d_model - case.d_true)) < 1e-9

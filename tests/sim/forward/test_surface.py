"""The datum height field: analytic gradient, local normal, form size, cloud."""

import numpy as np
import pytest

from metrology.sim.forward import DatumSurface, draw_surface, flat_surface, sample_cloud


def _formed(rng):
    c = rng.normal(size=(5, 5)) * 0.1
    return DatumSurface(rng.normal(size=3) * 1000, rng.normal(size=3), rng.normal(size=3), None, (350.0, 420.0),
                        0.3, -0.2, 0.15, c)


def test_gradient_matches_finite_differences(rng):
    surf = _formed(rng)
    s, t = rng.uniform(-300, 300, 20), rng.uniform(-400, 400, 20)
    hs, ht = surf.gradient(s, t)
    e = 1e-3
    fs = (surf.height(s + e, t) - surf.height(s - e, t)) / (2 * e)
    ft = (surf.height(s, t + e) - surf.height(s, t - e)) / (2 * e)
    assert np.allclose(hs, fs, atol=1e-9) and np.allclose(ht, ft, atol=1e-9)
    assert np.max(np.abs(hs)) > 1e-5  # the form is not trivially flat


def test_local_normal_is_perpendicular_to_the_surface(rng):
    surf = _formed(rng)
    s, t = rng.uniform(-300, 300, 10), rng.uniform(-400, 400, 10)
    m = surf.normal_at(s, t)
    e = 1e-3
    ds = surf.point(s + e, t) - surf.point(s - e, t)
    dt = surf.point(s, t + e) - surf.point(s, t - e)
    assert np.allclose(np.sum(m * ds, axis=1), 0, atol=1e-9)
    assert np.allclose(np.sum(m * dt, axis=1), 0, atol=1e-9)
    assert np.all(m @ surf.normal > 0)


def test_flat_surface_frame_is_orthonormal():
    surf = flat_surface([0, 0, 2000], [0.2, -0.1, -1])
    B = np.stack([surf.axis_s, surf.axis_t, surf.normal])
    assert np.allclose(B @ B.T, np.eye(3), atol=1e-12)
    assert np.allclose(np.cross(surf.axis_s, surf.axis_t), surf.normal)
    assert np.allclose(surf.normal_at(np.array([10.0]), np.array([-5.0])), surf.normal)


@pytest.mark.parametrize("shape", ["bow", "twist", "higher", "mixed"])
def test_drawn_form_has_the_asked_peak_to_valley(shape, rng):
    surf, truth = draw_surface(rng, form_mm=0.3, shape=shape)
    assert surf.form_peak_to_valley() == pytest.approx(0.3, rel=1e-9)
    assert truth["shape"] == shape
    assert 1500 <= np.linalg.norm(surf.origin) <= 2500


def test_cloud_lies_on_the_surface_within_its_noise(rng):
    surf, _ = draw_surface(rng, form_mm=0.4, shape="mixed")
    pts = sample_cloud(surf, rng, 4000, noise_mm=0.01)
    s, t, w = surf.plane_coords(pts)
    r = w - surf.height(s, t)
    # isotropic 10 um noise: the height residual is ~N(0, 0.01) (the tangential part moves h negligibly)
    assert abs(np.std(r) - 0.01) < 0.01 * 5 / np.sqrt(2 * 4000) + 1e-4
    assert abs(np.mean(r)) < 5 * 0.01 / np.sqrt(4000)

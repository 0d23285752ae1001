"""The torus lip (issue 53) against its own geometry: every surface point a tube's radius from the ring."""

import numpy as np
import pytest

from metrology.sim.forward import TorusPanel


def _ring_distance(p, panel):
    """Distance of points ``p (h, 3)`` from the torus's ring circle, and the unit vector from it to them."""
    r, Rm = panel.tube_mm, panel.ring_mm
    zc = -(Rm + r) if panel.side == "outer" else Rm - r
    q = p - np.array([0.0, 0.0, zc])
    radial = np.stack([q[:, 0], np.zeros(len(q)), q[:, 2]], 1)
    rho = np.linalg.norm(radial, axis=1)
    c = radial / rho[:, None] * Rm  # the nearest point of the ring (in the plane y = 0)
    v = q - c
    dist = np.linalg.norm(v, axis=1)
    return dist, v / dist[:, None]


@pytest.mark.parametrize("side", ["outer", "inner"])
def test_rays_hit_the_torus_and_normals_face_the_head(side):
    rng = np.random.default_rng(7)
    panel = TorusPanel(50.0, 600.0, side)
    o = np.column_stack([rng.uniform(-80, 80, 200), rng.uniform(-30, 30, 200), np.full(200, 90.0)])
    u = np.column_stack([rng.uniform(-0.2, 0.2, 200), rng.uniform(-0.2, 0.2, 200), -np.ones(200)])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    t = panel.intersect(o, u)
    ok = np.isfinite(t)
    assert ok.mean() > 0.9
    p = o[ok] + t[ok, None] * u[ok]
    dist, out = _ring_distance(p, panel)
    np.testing.assert_allclose(dist, 50.0, atol=1e-8)
    n = panel.normal_at(p)
    np.testing.assert_allclose(n, out, atol=1e-6)  # away from the tube's centre (on the inner side: toward the axis)
    assert (n[:, 2] > 0).all()


@pytest.mark.parametrize("side", ["outer", "inner"])
def test_curvatures_at_the_crest(side):
    panel = TorusPanel(40.0, 500.0, side)
    S = panel.shape_at(np.zeros((1, 3)))[0]
    kx = 1.0 / 540.0 if side == "outer" else -1.0 / 460.0
    np.testing.assert_allclose([S[0, 0], S[1, 1], S[0, 1]], [kx, 1.0 / 40.0, 0.0], atol=2e-6)


def test_bad_torus_refused():
    with pytest.raises(ValueError, match="tube radius"):
        TorusPanel(50.0, 40.0)
    with pytest.raises(ValueError, match="side"):
        TorusPanel(50.0, 600.0, "top")

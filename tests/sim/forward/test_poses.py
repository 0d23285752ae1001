"""Poses and rigid pose errors."""

import numpy as np

from metrology.sim.forward import draw_head, draw_poses, draw_surface, perturb_poses, tilt_of
from metrology.core.frames import random_rotation


def test_rigid_perturbation_preserves_distances_and_has_the_asked_size(rng):
    R = random_rotation(rng, 30)
    T = rng.normal(size=(30, 3)) * 1000
    R2, T2, omega, delta = perturb_poses(rng, R, T, angle_rad=5e-4, offset_mm=0.03)
    pts = rng.normal(size=(8, 3)) * 50  # TCS
    a = np.einsum("pij,nj->pni", R, pts) + T[:, None]
    b = np.einsum("pij,nj->pni", R2, pts) + T2[:, None]
    da = np.linalg.norm(a[:, :, None] - a[:, None], axis=-1)
    db = np.linalg.norm(b[:, :, None] - b[:, None], axis=-1)
    assert np.allclose(da, db, atol=1e-9)
    assert np.allclose(np.linalg.det(R2), 1.0)
    rel = np.einsum("pji,pjk->pik", R, R2)  # R^T R2 = Rot(omega)
    ang = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert np.allclose(ang, 5e-4, atol=1e-9)
    assert np.allclose(np.linalg.norm(T2 - T, axis=1), 0.03, atol=1e-12)
    # a point 50 mm off the TCS origin moves by up to ~ 50 * angle + offset
    assert np.max(np.linalg.norm(a - b, axis=-1)) <= 0.03 + np.max(np.linalg.norm(pts, axis=1)) * 5e-4 + 1e-9


def test_drawn_poses_stay_inside_tilt_range_and_extent(rng):
    head = draw_head(rng, 4, noise_mm=0.005)
    surf, _ = draw_surface(rng, form_mm=0.2, shape="bow")
    R, T, hits = draw_poses(rng, surf, head.true.zero, head.true.direction, 120, tilt_max_rad=np.radians(14),
                            range_mm=(30, 70), z0_mm=head.z0_mm)
    assert R.shape == (120, 3, 3) and np.all(hits.valid)
    assert np.all((hits.d >= 31) & (hits.d <= 69))
    tilt = tilt_of(R, surf)
    assert tilt.max() <= np.radians(14) + 1e-12
    assert tilt.max() > np.radians(8)  # the tilts do spread out to the limit
    s, t, _ = surf.plane_coords(hits.spot)
    assert np.all(surf.inside(s, t))


def test_head_errors_are_within_the_stated_ranges(rng):
    for n in (3, 4):
        head = draw_head(rng, n)
        dz = np.linalg.norm(head.true.zero - head.nominal.zero, axis=1)
        ang = np.degrees(np.arccos(np.clip(np.sum(head.true.direction * head.nominal.direction, 1), -1, 1)))
        assert np.all((dz >= 0.1 - 1e-12) & (dz <= 1.0 + 1e-12))
        assert np.all((ang >= 0.1 - 1e-6) & (ang <= 2.0 + 1e-6))
        r = np.linalg.norm(head.nominal.zero[:, :2], axis=1)
        assert np.allclose(r, head.radius_mm) and 30 <= head.radius_mm <= 60
        incl = np.degrees(np.arccos(head.nominal.direction[:, 2]))
        assert np.all((incl >= 15 - 1e-9) & (incl <= 35 + 1e-9))
        radial_in = -np.sum(head.nominal.direction[:, :2] * head.nominal.zero[:, :2], axis=1)
        assert np.all(radial_in > 0)  # beams lean toward the axis

"""Normals and attitude (Eqs. 17-22)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metrology.core.frames import random_rotation
from metrology.core.model import readings
from metrology.core.normals import (
    angle_between,
    attitude_angles,
    micro_plane_normal,
    normal_eq18,
    normal_from_angles,
    normal_lsq,
    projection_points,
    rot_x,
    rot_y,
)
from metrology.core.paper import table2_layouts, table6_layouts


def test_projection_points_refuse_non_unit_direction():
    with pytest.raises(ValueError, match="unit beam directions"):
        projection_points(np.zeros((1, 3)), np.array([[0, 0, 2.0]]), np.array([[1.0]]))


@pytest.mark.parametrize("tables", [table2_layouts, table6_layouts])
def test_micro_plane_recovers_plane_normal_exactly(tables, rng):
    _, true = tables()
    sign = np.sign(true.direction[:, 2].mean())
    for _ in range(20):
        n = np.array([*rng.normal(scale=0.1, size=2), 1.0])
        n /= np.linalg.norm(n)
        foot = np.array([0.0, 0.0, sign * rng.uniform(30.0, 60.0)])  # a point of the plane on the beam side
        d, valid = readings(true.zero, true.direction, n[None], np.array([-n @ foot]))
        assert valid.all()
        S = projection_points(true.zero, true.direction, d)
        for est in (normal_eq18(S), normal_lsq(S), micro_plane_normal(true.zero, true.direction, d)):
            assert np.rad2deg(angle_between(est[0], n)) < 1e-9


def test_normal_lsq_any_n_and_missing(rng):
    pts = rng.uniform(-20, 20, size=(1, 6, 3))
    pts[..., 2] = 0.1 * pts[..., 0] - 0.2 * pts[..., 1] + 5
    truth = np.array([-0.1, 0.2, 1.0]) / np.linalg.norm([-0.1, 0.2, 1.0])
    assert angle_between(normal_lsq(pts)[0], truth) < 1e-12
    pts[0, 2] = np.nan
    assert angle_between(normal_lsq(pts)[0], truth) < 1e-12
    pts[0, 1:5] = np.nan  # only 2 points left
    assert np.all(np.isnan(normal_lsq(pts)[0]))


def test_eq18_needs_four_points():
    with pytest.raises(ValueError, match="exactly 4"):
        normal_eq18(np.zeros((1, 3, 3)))


@settings(max_examples=100, deadline=None)
@given(theta=st.floats(-1.5, 1.5), phi=st.floats(-1.5, 1.5))
def test_attitude_angles_rebuild_the_normal(theta, phi):
    n = normal_from_angles(theta, phi)
    # Eq. 20 written out: Rot(Y, theta) Rot(X, phi) e_z
    np.testing.assert_allclose(n, rot_y(theta) @ rot_x(phi) @ [0, 0, 1.0], atol=1e-14)
    np.testing.assert_allclose(n, [np.sin(theta) * np.cos(phi), -np.sin(phi), np.cos(theta) * np.cos(phi)], atol=1e-14)
    t2, p2 = attitude_angles(n)
    np.testing.assert_allclose([t2, p2], [theta, phi], atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_attitude_round_trip_from_normals(seed):
    rng = np.random.default_rng(seed)
    n = rng.normal(size=3)
    n[2] = abs(n[2]) + 0.05
    n /= np.linalg.norm(n)
    np.testing.assert_allclose(normal_from_angles(*attitude_angles(n)), n, atol=1e-12)


def test_attitude_rejects_normals_behind_the_tool():
    with pytest.raises(ValueError, match="n_z > 0"):
        attitude_angles(np.array([0, 0, -1.0]))


def test_angle_between_is_precise_at_small_angles():
    a = np.array([0, 0, 1.0])
    b = np.array([1e-9, 0, 1.0])
    assert abs(angle_between(a, b) - 1e-9) < 1e-20
    assert angle_between(a, -a) == 0.0 and abs(angle_between(a, -a, oriented=True) - np.pi) < 1e-15


def test_random_rotation_is_seeded():
    assert np.array_equal(random_rotation(np.random.default_rng(1)), random_rotation(np.random.default_rng(1)))

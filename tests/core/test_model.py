"""The measurement model (Eqs. 1-9): known answers, Jacobians, gauge, invalid geometry."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metrology.core.frames import random_rotation
from metrology.core.model import (
    direction_from_tangent,
    gauge_null_vector,
    jacobian_raw,
    jacobian_tangent,
    readings,
    tangent_from_direction,
)
from metrology.core.paper import table2_layouts, table6_layouts


def test_known_answer_by_hand():
    # plane z = 50; sensor at the origin looking up: d = 50; tilted by a: d = 50 / cos a
    a = np.deg2rad(30.0)
    zero = np.zeros((2, 3))
    direction = np.array([[0, 0, 1.0], [np.sin(a), 0, np.cos(a)]])
    d, valid = readings(zero, direction, np.array([[0, 0, 1.0]]), np.array([-50.0]))
    assert valid.all()
    np.testing.assert_allclose(d[0], [50.0, 50.0 / np.cos(a)], rtol=0, atol=1e-12)


def test_rigid_transform_invariance(rng):
    nominal, true = table2_layouts()
    normal = np.array([[0.01, -0.02, 1.0]])
    normal /= np.linalg.norm(normal)
    offset = np.array([45.0])
    d0, _ = readings(true.zero, true.direction, normal, offset)
    R, t = random_rotation(rng), rng.normal(scale=500, size=3)
    # move sensors and plane together: p -> R p + t; plane n.p + D = 0 -> (R n).p' + D - (R n).t = 0
    n2 = normal @ R.T
    d1, _ = readings(true.zero @ R.T + t, true.direction @ R.T, n2, offset - n2 @ t)
    np.testing.assert_allclose(d1, d0, atol=1e-9)


def test_any_number_of_sensors():
    zero = np.array([[10.0 * np.cos(t), 10.0 * np.sin(t), 0.0] for t in np.linspace(0, 2 * np.pi, 7)[:-1]])
    direction = np.tile([0, 0, 1.0], (6, 1))
    d, valid = readings(zero, direction, np.array([[0, 0, 1.0], [0, 0, 1.0]]), np.array([-20.0, -30.0]))
    assert d.shape == (2, 6) and valid.all()
    np.testing.assert_allclose(d, [[20.0] * 6, [30.0] * 6])


def _fd(fun, x, eps=1e-6):
    cols = []
    for k in range(len(x)):
        dx = np.zeros_like(x)
        dx[k] = eps
        cols.append((fun(x + dx) - fun(x - dx)) / (2 * eps))
    return np.stack(cols, axis=-1)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_jacobians_match_finite_differences(seed):
    rng = np.random.default_rng(seed)
    nominal, _ = table6_layouts()
    tilt = rng.normal(scale=0.1, size=3)
    normal = np.array([tilt[0], tilt[1], -1.0])
    normal /= np.linalg.norm(normal)
    offset = np.array([rng.uniform(30, 60)])
    E = nominal.zero[0] + rng.normal(scale=1.0, size=3)
    u = nominal.direction[0] + rng.normal(scale=0.05, size=3)

    J = jacobian_raw(E[None], u[None], normal[None], offset)[0, 0]
    J_fd = _fd(lambda x: readings(x[None, :3], x[None, 3:], normal[None], offset)[0][0, 0], np.r_[E, u])
    np.testing.assert_allclose(J, J_fd, rtol=1e-6, atol=1e-6)

    ab = rng.normal(scale=0.05, size=2)
    u0 = nominal.direction[:1]
    Jt = jacobian_tangent(E[None], u0, ab[None], normal[None], offset)[0, 0]
    Jt_fd = _fd(lambda x: readings(x[None, :3], direction_from_tangent(u0, x[None, 3:]), normal[None], offset)[0][0, 0],
                np.r_[E, ab])
    np.testing.assert_allclose(Jt, Jt_fd, rtol=1e-6, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(scale=st.floats(0.01, 100.0), seed=st.integers(0, 2**31 - 1))
def test_gauge_direction_scale_is_unidentifiable(scale, seed):
    rng = np.random.default_rng(seed)
    _, true = table2_layouts()
    # 12 poses, tilts of about 10 deg: more rows than the 6 raw parameters, so rank 5 below says
    # something (5 poses have rank <= 5 whatever the gauge, and a near-degenerate draw of them rank 4)
    normal = rng.normal(scale=0.15, size=(12, 3)) + [0, 0, 1.0]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offset = rng.uniform(30, 60, size=12)
    d1, _ = readings(true.zero, true.direction, normal, offset)
    d2, _ = readings(true.zero, true.direction * scale, normal, offset)
    np.testing.assert_allclose(d2, d1, rtol=1e-12)
    J = jacobian_raw(true.zero, true.direction, normal, offset)
    null = gauge_null_vector(true.direction)
    np.testing.assert_allclose(np.einsum("pnk,nk->pn", J, null), 0.0, atol=1e-9)
    # and the raw Jacobian stacked over poses has rank 5, not 6, per sensor
    assert np.linalg.matrix_rank(J[:, 0, :], tol=1e-8 * np.abs(J).max()) == 5


def test_invalid_geometry_is_masked_not_silent():
    zero = np.zeros((3, 3))
    direction = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 0, 1.0]])  # parallel, away, ok
    normal = np.array([[0, 0, 1.0]])
    d, valid = readings(zero, direction, normal, np.array([-10.0]))
    assert valid.tolist() == [[False, False, True]]
    assert np.isnan(d[0, 0]) and np.isnan(d[0, 1]) and d[0, 2] == 10.0
    d, valid = readings(np.array([[np.nan, 0, 0]] * 3), direction, normal, np.array([-10.0]))
    assert not valid.any() and np.all(np.isnan(d))


def test_shape_errors_raise():
    with pytest.raises(ValueError, match="zero: expected shape"):
        readings(np.zeros(3), np.zeros(3), np.array([[0, 0, 1.0]]), np.array([1.0]))
    with pytest.raises(ValueError, match="plane: normal"):
        readings(np.zeros((2, 3)), np.ones((2, 3)), np.array([[0, 0, 1.0]]), np.array([1.0, 2.0]))


@settings(max_examples=50, deadline=None)
@given(a=st.floats(-0.5, 0.5), b=st.floats(-0.5, 0.5))
def test_chart_round_trip(a, b):
    nominal, _ = table6_layouts()
    u0 = nominal.direction[:1]
    u = direction_from_tangent(u0, np.array([[a, b]]))
    np.testing.assert_allclose(np.linalg.norm(u), 1.0, atol=1e-12)
    np.testing.assert_allclose(tangent_from_direction(u0, u), [[a, b]], atol=1e-10)

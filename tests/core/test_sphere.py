"""Tests of metrology.core.sphere: the micro-sphere normal and the algebraic sphere fit."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metrology.core.normals import angle_between, micro_plane_normal
from metrology.core.paper import table2_layouts, table6_layouts
from metrology.core.sphere import fit_algebraic_sphere, micro_sphere_normal
from metrology.panel.head import default_standoff, tool_axis_tcs

LAYOUTS = {"table6": table6_layouts()[1], "table2": table2_layouts()[1]}


def random_rotation(rng):
    from scipy.spatial.transform import Rotation

    return Rotation.random(random_state=np.random.RandomState(int(rng.integers(1 << 31)))).as_matrix()


def sphere_spots(layout, R_sphere, tilt, rng):
    """Beams of a tilted head meeting an analytic sphere; exact spots (TCS) and the true normal (TCS)."""
    a = tool_axis_tcs(layout)
    standoff = default_standoff(layout)
    z0 = float(np.mean(layout.zero @ a))
    # TCS: drilling point on the axis at z0 + standoff; sphere centre behind it along the tilted normal
    P = a * (z0 + standoff)
    w = np.cross(a, rng.normal(size=3))
    w /= np.linalg.norm(w)
    from scipy.spatial.transform import Rotation

    n_out = Rotation.from_rotvec(w * tilt).apply(-a)  # outward normal at P, tilted off the axis
    C = P - R_sphere * n_out
    E, u = layout.zero, layout.direction
    b = np.sum(u * (E - C), axis=1)
    c = np.sum((E - C) ** 2, axis=1) - R_sphere**2
    d = -b - np.sqrt(b * b - c)  # first intersection
    return d, n_out


@pytest.mark.parametrize("lname", sorted(LAYOUTS))
@pytest.mark.parametrize("R_sphere", [300.0, 800.0, 3000.0])
def test_micro_sphere_exact_on_a_sphere_without_noise(lname, R_sphere):
    layout = LAYOUTS[lname]
    rng = np.random.default_rng(7)
    for _ in range(5):
        d, n_out = sphere_spots(layout, R_sphere, math.radians(2.0), rng)
        n, rad, _, miss = micro_sphere_normal(layout.zero, layout.direction, d[None], axis=tool_axis_tcs(layout),
                                                 prior_radius_mm=math.inf)
        assert not miss[0]
        assert rad[0] == pytest.approx(R_sphere, rel=1e-5)
        assert angle_between(n[0], n_out, oriented=True) < 1e-7


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), r=st.floats(5.0, 60.0), n=st.integers(4, 7))
def test_sphere_through_coplanar_points_is_the_plane(seed, r, n):
    """Coplanar spots (concyclic or not) under a random rigid motion: the sphere is the plane."""
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = r * rng.uniform(0.5, 1.0, n)
    local = np.column_stack([rad * np.cos(ang), rad * np.sin(ang), np.zeros(n)])
    Rm = random_rotation(rng)
    S = local @ Rm.T + rng.uniform(-500, 500, 3)
    u, c, s = fit_algebraic_sphere(S[None])
    assert np.all(np.isfinite(u))
    assert abs(u[0, 0]) < 1e-6  # A ~ 0: a plane
    assert angle_between(u[0, 1:4], Rm[:, 2]) < 1e-6


def test_nearly_flat_sphere_does_not_blow_up():
    layout = LAYOUTS["table6"]
    rng = np.random.default_rng(2)
    for R in (1e4, 1e6, 1e9, 1e12):
        d, n_out = sphere_spots(layout, R, math.radians(1.0), rng)
        n, rad, pt, _ = micro_sphere_normal(layout.zero, layout.direction, d[None], axis=tool_axis_tcs(layout))
        assert np.all(np.isfinite(n)) and np.all(np.isfinite(pt))
        assert angle_between(n[0], n_out, oriented=True) < math.radians(0.01)


def test_three_sensors_fall_back_to_the_plane():
    layout = LAYOUTS["table6"].subset(["L1", "L2", "L3"])
    d = np.array([[40.0, 41.0, 40.5]])
    n_s, rad, _, _ = micro_sphere_normal(layout.zero, layout.direction, d, axis=tool_axis_tcs(layout))
    n_p = micro_plane_normal(layout.zero, layout.direction, d)
    assert np.isinf(rad[0])
    assert angle_between(n_s[0], n_p[0], oriented=True) < 1e-12


def test_nan_reading_gives_nan_not_a_number():
    layout = LAYOUTS["table2"]
    d = np.array([[50.0, np.nan, 50.0, 50.0]])
    n, rad, _, _ = micro_sphere_normal(layout.zero, layout.direction, d, axis=tool_axis_tcs(layout))
    assert np.all(np.isnan(n)) and np.isnan(rad[0])

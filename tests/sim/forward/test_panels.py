"""The log simulator's panels: closed-form ray hits checked against the implicit surfaces and a root finder."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import brentq

from metrology.sim.forward.panels import CylinderPanel, FlatPanel, SpherePanel, make_panel

PANELS = [FlatPanel(), SpherePanel(600.0), CylinderPanel(500.0, (1.0, 1.0, 0.0)), CylinderPanel(2000.0)]


def implicit(panel, p):
    """Signed distance-like residual, > 0 outside (the head's side), written from each surface's definition."""
    p = np.asarray(p, float)
    if panel.kind == "flat":
        return p[..., 2]
    c = np.array([0.0, 0.0, -panel.radius_mm])
    q = p - c
    if panel.kind == "cylinder":
        a = np.asarray(panel.axis)
        q = q - (q @ a)[..., None] * a
    return np.linalg.norm(q, axis=-1) - panel.radius_mm


def rays(rng, n):
    """Origins 20-100 mm above the panel's top over +-150 mm, directions within 40 deg of -z."""
    e = np.column_stack([rng.uniform(-150, 150, (n, 2)), rng.uniform(20, 100, n)])
    tilt, az = rng.uniform(0, math.radians(40), n), rng.uniform(0, 2 * math.pi, n)
    u = np.column_stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), -np.cos(tilt)])
    return e, u


@pytest.mark.parametrize("panel", PANELS, ids=lambda p: p.kind + str(getattr(p, "radius_mm", "")))
def test_hit_lies_on_the_surface_and_is_the_first_root(panel):
    rng = np.random.default_rng(11)
    e, u = rays(rng, 200)
    t = panel.intersect(e, u)
    assert np.all(np.isfinite(t)) and np.all(t >= 0)
    spot = e + t[:, None] * u
    assert np.max(np.abs(implicit(panel, spot))) < 1e-9  # on the surface to 1e-9 mm
    for i in range(0, 200, 20):  # a root finder on the implicit surface along the beam finds the same hit
        f = lambda tau: float(implicit(panel, e[i] + tau * u[i]))  # noqa: E731
        grid = np.linspace(0, t[i] * 1.5 + 1, 400)
        vals = np.array([f(g) for g in grid])
        k = np.flatnonzero(vals[:-1] * vals[1:] <= 0)[0]  # the first sign change
        assert brentq(f, grid[k], grid[k + 1], xtol=1e-12) == pytest.approx(t[i], abs=1e-8)


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-200, 200), y=st.floats(-200, 200), z=st.floats(5, 200), tilt=st.floats(0, 1.2),
       az=st.floats(0, 6.3), kind=st.sampled_from(range(len(PANELS))))
def test_any_downward_ray_hits_on_the_surface(x, y, z, tilt, az, kind):
    panel = PANELS[kind]
    e = np.array([x, y, z + float(np.nan_to_num(panel.height(x, y)))])
    u = np.array([math.sin(tilt) * math.cos(az), math.sin(tilt) * math.sin(az), -math.cos(tilt)])
    t = float(panel.intersect(e, u))
    if np.isfinite(t):
        assert t >= 0 and abs(implicit(panel, e + t * u)) < 1e-8
    else:  # a miss is only possible on a curved panel, for a ray that stays outside
        assert panel.kind != "flat"
        assert np.all(implicit(panel, e + np.linspace(0, 2000, 2001)[:, None] * u) > 0)


@pytest.mark.parametrize("panel", PANELS[1:], ids=lambda p: p.kind)
def test_rays_running_away_or_beside_miss(panel):
    up = panel.intersect(np.array([0.0, 0.0, 50.0]), np.array([0.0, 0.0, 1.0]))
    beside = panel.intersect(np.array([0.0, 0.0, 50.0]), np.array([1.0, 0.0, 0.0]) if panel.kind == "sphere"
                             else np.asarray(panel.axis))
    assert np.isnan(up) and np.isnan(beside)
    assert np.isnan(FlatPanel().intersect(np.array([0.0, 0.0, -5.0]), np.array([0.0, 0.0, -1.0])))  # from behind


@pytest.mark.parametrize("panel", PANELS, ids=lambda p: p.kind)
def test_normal_is_the_height_fields_normal(panel):
    rng = np.random.default_rng(5)
    P = panel.sample(rng, 50, 150.0)
    assert np.all(np.abs(P[:, :2]) <= 150.0) and np.max(np.abs(implicit(panel, P))) < 1e-9
    h = 1e-4
    hx = (panel.height(P[:, 0] + h, P[:, 1]) - panel.height(P[:, 0] - h, P[:, 1])) / (2 * h)
    hy = (panel.height(P[:, 0], P[:, 1] + h) - panel.height(P[:, 0], P[:, 1] - h)) / (2 * h)
    m = np.column_stack([-hx, -hy, np.ones(len(P))])
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    assert np.max(np.abs(panel.normal_at(P) - m)) < 1e-7


def test_bad_panels_are_refused():
    with pytest.raises(ValueError, match="expected one of flat, sphere, cylinder"):
        make_panel("cone", 500)
    with pytest.raises(ValueError, match="needs a radius"):
        make_panel("sphere")
    with pytest.raises(ValueError, match="positive"):
        make_panel("cylinder", -3)
    with pytest.raises(ValueError, match="xy plane"):
        CylinderPanel(500, (0, 0, 1))
    with pytest.raises(ValueError, match="0.9 R"):
        SpherePanel(500).check_patch(400)

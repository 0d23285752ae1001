"""The CAD beyond the quartic over a footprint large against the radius (metrology/panel/footprint.py):
against the analytic heights of the forward simulator's cylinders, meshed as a tessellator would."""

import numpy as np
import pytest

from metrology.measure.beyond import _TAYLOR, _degrees_beyond
from metrology.measure.panel import HoleTable
from metrology.panel.holes import panel_surfaces
from metrology.panel.mesh import Panel
from metrology.sim.forward.panels import make_panel
from tests.measure.panel_fixtures import panel_mesh


def _surfaces(R, footprint, axis=(1.0, 0.0, 0.0)):
    panel = make_panel("cylinder", R, axis=axis)
    P = np.array([[0.0, 0.0, 0.0], [10.0 * axis[0], 10.0 * axis[1], 0.0]])
    return panel_surfaces(Panel(panel_mesh(panel, half_mm=160.0, step_mm=2.0)),
                          HoleTable(("a", "b"), P, np.tile([0.0, 0.0, -1.0], (2, 1)), "holes"), footprint)


def _beyond_second(higher, s, t):
    """The height (mm) of ``higher``'s terms at ``s, t`` mm."""
    s, t = np.array([[s]], float), np.array([[t]], float)
    c = higher[:, :9].T / _TAYLOR[:, None]
    w = (s * (c[0] * s * s + c[1] * s * t + c[2] * t * t) + c[3] * t ** 3
         + s * s * (c[4] * s * s + c[5] * s * t + c[6] * t * t) + t * t * (c[7] * s * t + c[8] * t * t))
    return float((w + _degrees_beyond(higher[:, 9:], s, t))[0, 0])


@pytest.mark.parametrize("R", [50.0, 80.0])
def test_the_cylinder_s_height_beyond_second_order_is_carried_to_a_fraction_of_a_micrometre(R):
    f = _surfaces(R, 26.6)
    assert f["higher"].shape == (2, 39)
    np.testing.assert_allclose(f["k"][:, 0], 1.0 / R, rtol=1e-4)  # the curvature from the vertices near the point
    for t in (-25.0, 12.0, 25.0):  # across the axis (e2 = y): the circle's height beyond -t^2 / 2R
        truth = np.sqrt(R * R - t * t) - R + t * t / (2 * R)
        assert abs(_beyond_second(f["higher"][:1], 0.0, t) - truth) < 2e-4, t  # the quartic alone: 54 um off at R 50
        assert abs(_beyond_second(f["higher"][:1], 20.0, 0.0)) < 2e-4  # along the axis: straight
    assert np.all(f["u_height"] < 1e-3) and np.all(f["u_height"] > 0)


def test_a_radius_large_against_the_footprint_needs_no_terms_beyond_the_quartic():
    f = _surfaces(500.0, 26.6)
    assert f["higher"].shape == (2, 9) and np.all(f["u_height"] == 0)


def test_a_footprint_past_the_crest_is_named_so():
    f = _surfaces(20.0, 26.6)
    assert all("past the crest of the surface's radius 20 mm" in p for p in f["problem"])

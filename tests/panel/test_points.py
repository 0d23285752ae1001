"""Tests of metrology.panel.points: reading, gridding and snapping drilling points."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metrology.panel.points import grid_points, read_points
from metrology.panel.rays import RayCaster

from .helpers import make_panel


@settings(max_examples=30, deadline=None)
@given(pts=st.lists(st.tuples(*[st.floats(-1e4, 1e4, allow_nan=False)] * 3), min_size=1, max_size=20),
       header=st.booleans())
def test_read_points_round_trip(tmp_path_factory, pts, header):
    path = tmp_path_factory.mktemp("p") / "p.csv"
    text = ("x,y,z\n" if header else "") + "".join(f"{x!r},{y!r},{z!r}\n" for x, y, z in pts)
    path.write_text(text)
    d = read_points(path)
    assert np.array_equal(d.points, np.array(pts, float))
    assert np.all(np.isnan(d.approach))


@pytest.mark.parametrize("text, match", [
    ("x,y,z\n1,2\n", "line 2: expected 3"),
    ("1,2,abc\n", "line 1: 'abc' is not a number"),
    ("1,2,3,0,0,0\n", "line 1: approach direction is the zero vector"),
    ("a,b,c\n", "line 1: header must be"),
    ("# nothing\n", "no drilling points"),
])
def test_read_points_errors(tmp_path, text, match):
    p = tmp_path / "p.csv"
    p.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_points(p)


def test_grid_points_cover_the_panel_on_its_axes():
    panel = make_panel("cylinder", 300.0, half=50.0, spacing=2.0)
    caster = RayCaster(panel.mesh)
    g = grid_points(panel, 15.0, caster)  # 6 steps of 15 over 100 mm: nodes at -45..45
    assert len(g.points) == 7 * 7
    # on the surface and on a grid aligned with the panel's x and y
    # within the chord sag of a 2 mm grid on R 300 (h^2 / 8R = 1.7 um)
    assert np.max(np.abs(g.points[:, 2] - panel.surface.height(g.points[:, 0], g.points[:, 1]))) < 2e-3
    assert np.allclose(np.unique(np.round(g.points[:, 1], 6)), np.arange(-45, 46, 15.0))

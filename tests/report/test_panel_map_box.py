"""The measure report's panel map draws the panel under its holes (issue 51 item 6 and its "done when": the
report shows the panel with its holes coloured by angle; the walk found the holes alone, on blank axes)."""

import numpy as np
import trimesh

from metrology.jobs.measure_map import panel_box
from metrology.report.panel_map import PANEL_FILL, PanelMap, panel_map_figure


def test_a_mesh_panels_box_is_read_in_mm_and_drawn_under_the_holes(tmp_path):
    x, y = np.meshgrid(np.linspace(-600, 600, 7), np.linspace(-400, 400, 5), indexing="ij")
    v = np.c_[x.ravel(), y.ravel(), -(x.ravel() ** 2) / 3000.0]
    idx = np.arange(35).reshape(7, 5)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    trimesh.Trimesh(v / 25.4, np.r_[np.c_[a, b, c], np.c_[a, c, d]], process=False).export(tmp_path / "skin.stl")
    lo, hi = panel_box(tmp_path / "skin.stl", "in")
    assert np.allclose(lo, [-600, -400, -120], atol=1e-3) and np.allclose(hi, [600, 400, 0], atol=1e-3)
    assert panel_box(None) is None and panel_box(tmp_path / "wing.step") is None  # not tessellated for a figure
    point = np.array([[-500.0, -300.0, -83.3], [0.0, 0.0, 0.0], [500.0, 300.0, -83.3]])
    m = PanelMap(("A", "B", "C"), point, np.array([0.1, 0.2, np.nan]), np.array(["conforms", "conforms", ""]),
                 "skin.stl", (lo, hi))
    ax = panel_map_figure(m, 0.5).axes[0]
    (box,) = [p for p in ax.patches if np.allclose(p.get_facecolor()[:3], [0xF2 / 255] * 3)]
    assert np.allclose([*box.get_xy(), box.get_width(), box.get_height()], [-600, -400, 1200, 800], atol=1e-3)
    x0, x1 = ax.get_xlim()
    assert x0 <= -600 and x1 >= 600  # the whole panel in view, not the holes' spread alone
    assert PANEL_FILL == "#f2f2f2"

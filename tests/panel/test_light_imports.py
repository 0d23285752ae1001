"""What loading a panel and its holes' surfaces imports: a small hole table on an STL needs neither Open3D nor the
STEP reader's library (cascadio), which a STEP read still loads (metrology.panel._trimesh, DOUBLE_ENGINE_WORK)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from metrology.io.data import DATA_DIR

PANELS = DATA_DIR / "panels"

_SCRIPT = """
import json, sys
from metrology.panel.mesh import load_panel
from metrology.measure.panel import read_hole_table
from metrology.panel.holes import panel_surfaces
panel = load_panel(sys.argv[1])
s = panel_surfaces(panel, read_hole_table(sys.argv[2]), 30.0)
stand_in = type(sys.modules.get("cascadio")).__name__
out = {"open3d": "open3d" in sys.modules, "cascadio": stand_in, "holes": len(s["normal"])}
if len(sys.argv) > 3:
    out["step_faces"] = len(load_panel(sys.argv[3]).mesh.faces)
    out["cascadio_after"] = type(sys.modules.get("cascadio")).__name__
print(json.dumps(out))
"""


def _run(*args):
    p = subprocess.run([sys.executable, "-c", _SCRIPT, *map(str, args)], capture_output=True, text=True, check=True)
    return json.loads(p.stdout.splitlines()[-1])


def test_small_hole_table_loads_no_open3d():
    out = _run(PANELS / "wing.stl", PANELS / "wing.holes.csv")
    assert out["holes"] == 25
    assert out["open3d"] is False  # trimesh's own engine below DOUBLE_ENGINE_WORK: Open3D's library not loaded


def test_an_stl_never_loads_cascadio_a_step_read_after_does():
    pytest.importorskip("cascadio")  # the step / step-exact extra: CI's extras leg runs this test
    out = _run(PANELS / "wing.stl", PANELS / "wing.holes.csv", PANELS / "wing.step")
    assert out["holes"] == 25
    assert out["open3d"] is False
    assert out["cascadio"] == "_Deferred"  # the stand-in: never loaded for the STL
    assert out["step_faces"] > 0  # a STEP read afterwards loads the real library through it
    assert out["cascadio_after"] == "module"

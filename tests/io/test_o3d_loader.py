"""The one Open3D loader: Open3D without Plotly and Dash at import, its Plotly functions still there."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
import sys
import numpy as np
from metrology.io._o3d import open3d
o3d = open3d()
print("dash" in sys.modules, "plotly" in sys.modules)
cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.random.default_rng(0).normal(size=(10, 3))))
assert callable(o3d.visualization.draw_plotly)  # the package's name in Open3D 0.18 and 0.20
# get_plotly_fig: its module's in both (the package exports it in 0.20, not in 0.18)
fig = sys.modules["open3d.visualization.draw_plotly"].get_plotly_fig([cloud])
print(type(fig).__module__.split(".")[0], len(fig.data[0].x))
"""


def test_open3d_loads_without_plotly_and_dash_and_draw_plotly_still_works():
    # a fresh interpreter: another test may have loaded Plotly already
    r = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.split("\n")
    assert lines[0] == "False False"  # not loaded by Open3D's import
    assert lines[1] == "plotly 10"  # loaded at the first call, the real function's figure of the 10 points


ML_SCRIPT = """
import sys
from metrology.io._o3d import open3d
o3d = open3d()
print("sklearn" in sys.modules)
try:
    kitti = o3d.ml.datasets.KITTI  # Open3D 0.18: the real datasets module, loaded now
except ImportError:  # Open3D 0.20 without its ml extra: the same error as without the stand-in
    print("no ml extra")
else:
    print(kitti.__module__.split(".")[1], sys.modules["open3d.ml.datasets"] is o3d.ml.datasets)
"""


def test_open3d_loads_without_its_ml_datasets_and_they_still_load_when_asked():
    """Open3D 0.18 (the lowest allowed) loads scikit-learn at import for Open3D-ML's datasets: 1.4 s CPU a process."""
    r = subprocess.run([sys.executable, "-c", ML_SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.split("\n")
    assert lines[0] == "False"  # scikit-learn not loaded by Open3D's import
    assert lines[1] in ("_ml3d True", "no ml extra"), lines

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
print("sklearn" in sys.modules)  # Open3D 0.18 loads scikit-learn for Open3D-ML's datasets, behind a stand-in
"""


def test_open3d_loads_without_plotly_and_dash_and_draw_plotly_still_works():
    # a fresh interpreter: another test may have loaded Plotly already
    r = subprocess.run([sys.executable, "-c", SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.split("\n")
    assert lines[0] == "False False"  # not loaded by Open3D's import
    assert lines[1] == "plotly 10"  # loaded at the first call, the real function's figure of the 10 points
    assert lines[2] == "False"  # Open3D-ML's datasets not loaded (Open3D 0.18: scikit-learn, 1.4 s CPU a process)


def test_the_stand_in_loads_its_module_at_the_first_attribute_asked(tmp_path, monkeypatch):
    """:func:`metrology.io._o3d._lazy_module` (Open3D-ML's datasets): nothing loaded until asked, then the real module
    everywhere (in ``sys.modules`` and in its package)."""
    from metrology.io._o3d import _lazy_module

    (tmp_path / "metro_lazy_probe").mkdir()
    (tmp_path / "metro_lazy_probe" / "__init__.py").write_text("from . import heavy\n")
    (tmp_path / "metro_lazy_probe" / "heavy.py").write_text("LOADED = 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("metro_lazy_probe", "metro_lazy_probe.heavy"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    stub = _lazy_module("metro_lazy_probe.heavy")
    monkeypatch.setitem(sys.modules, "metro_lazy_probe.heavy", stub)
    import metro_lazy_probe

    assert metro_lazy_probe.heavy is stub and "LOADED" not in vars(stub)  # the package's import kept the stand-in
    assert stub.LOADED == 42  # the first attribute asked: the real module's
    real = sys.modules["metro_lazy_probe.heavy"]
    assert real is not stub and real.LOADED == 42 and metro_lazy_probe.heavy is real
    sys.modules.pop("metro_lazy_probe")


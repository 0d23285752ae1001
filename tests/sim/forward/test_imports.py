"""The simulator is independent of the fit: it imports nothing that computes readings or effects."""

import ast
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
FORWARD = ROOT / "metrology" / "sim" / "forward"
FORBIDDEN = ("metrology.core.model", "metrology.core.effects", "metrology.calibration", "metrology.diagnosis",
             "metrology.sim.synth", "metrology.sim.simulation",
             # the hole-log simulator (log*.py) must not borrow the normals it is meant to test
             "metrology.core.normals", "metrology.core.sphere", "metrology.panel", "metrology.measure",
             # nor the jobs: the metro controller the simulated cell is tested with is plugged in from
             # metrology.jobs.simulate_log, outside this package (issue 36)
             "metrology.jobs")

# ``metrology/__init__.py`` re-exports the whole library (the model included), so the check loads
# the ``metrology`` package without running it: what remains in sys.modules is what the forward
# package itself pulls in. Running a case and writing it executes the lazy imports too.
SCRIPT = f"""
import json, sys, tempfile, types
import numpy as np
pkg = types.ModuleType("metrology"); pkg.__path__ = [{str(ROOT / "metrology")!r}]
sys.modules["metrology"] = pkg
import metrology.sim.forward as fw
with tempfile.TemporaryDirectory() as d:
    fw.write_case(fw.draw_pair(np.random.default_rng(3), "drift", "pose_error"), d)
    from metrology.io.layout import load_layout
    lay = load_layout({str(ROOT / "metrology" / "data" / "measured" / "nominal.toml")!r})
    spec = fw.LogSpec(lay, lay, fw.make_panel("sphere", 800.0))
    fw.write_log_parquet(fw.simulate_log(spec, 0, 100, 2), d + "/log", d + "/truth.csv")
    # real panels: a bundled mesh and its hole table, a mesh ray-cast, a panel off its CAD, a foreign controller
    from metrology.sim.forward.meshes import MeshPanel, load_sim_panel, panel_mesh
    from metrology.sim.forward.holes import read_hole_table
    from metrology.sim.forward.shapes import parse_off_cad
    from metrology.sim.forward.log import MicroPlane
    panels = {str(ROOT / "metrology" / "data" / "panels")!r}
    cad = load_sim_panel(panels + "/wing.stl")[1]
    table = read_hole_table(panels + "/wing.holes.csv")
    stub = lambda layout, d, shape: MicroPlane()(layout, d)
    spec = fw.LogSpec(lay, lay, parse_off_cad("dent", cad), cad_panel=cad, table=table, controller=stub)
    fw.write_log_csv(fw.simulate_log(spec, 0, 60, 1), d + "/t.csv", d + "/t.truth.csv")
    mesh = MeshPanel(*panel_mesh(cad, 125.0, 10.0))
    spec = fw.LogSpec(lay, lay, mesh, table=table)
    fw.write_log_csv(fw.simulate_log(spec, 0, 30, 1), d + "/m.csv", d + "/m.truth.csv")
    mesh.shape_at(table.points[:2])
print(json.dumps(sorted(m for m in sys.modules if m.startswith("metrology"))))
"""


def _forbidden(mods):
    return [m for m in mods if any(m == f or m.startswith(f + ".") for f in FORBIDDEN)]


def test_forward_package_loads_no_model_effect_fit_or_old_simulator():
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, cwd=ROOT, check=True)
    mods = json.loads(out.stdout.strip().splitlines()[-1])
    assert "metrology.sim.forward.cases" in mods  # the check did load the package
    assert {"metrology.sim.forward.log", "metrology.sim.forward.log_write", "metrology.sim.forward.panels",
            "metrology.sim.forward.meshes", "metrology.sim.forward.holes", "metrology.sim.forward.shapes"} <= set(mods)
    assert _forbidden(mods) == []


def test_the_check_would_catch_a_forbidden_import():
    """The same loading (the package stubbed, sys.modules listed), a forbidden import added, the cases not run: the
    listing names it (running the cases, as above, only adds the lazy imports; 5 s of the default run)."""
    head = SCRIPT.split("with tempfile.TemporaryDirectory() as d:")[0]
    script = head.replace("import metrology.sim.forward as fw", "import metrology.sim.forward as fw\nimport metrology.core.model")
    script += 'print(json.dumps(sorted(m for m in sys.modules if m.startswith("metrology"))))\n'
    assert script != SCRIPT and "import metrology.core.model" in script
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, check=True)
    assert _forbidden(json.loads(out.stdout.strip().splitlines()[-1])) == ["metrology.core.model"]


def test_no_forbidden_import_anywhere_in_the_source():
    """Static check, in-function imports included (a lazy import the run above did not reach)."""
    for path in sorted(FORWARD.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            assert _forbidden(names) == [], f"{path.name} imports {names}"
            if isinstance(node, ast.ImportFrom):
                assert node.level == 0, f"{path.name}: relative import"

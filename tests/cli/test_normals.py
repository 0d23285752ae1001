"""Tests of ``metro normals``: JSON and per-point output, same seed same bytes, one-line fatal errors, the map."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from metrology.core.layout import SensorLayout
from metrology.core.paper import table6_layouts
from metrology.io.layout import save_layout
from metrology.panel.surfaces import ParametricSurface, panel_mesh, write_binary_stl


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("normals")
    surf = ParametricSurface("cylinder", 800.0)
    write_binary_stl(panel_mesh(surf, 100, 100, 1.0, 20.0), d / "cyl.stl", surf.tag)
    save_layout(table6_layouts()[0], d / "t6.toml")
    (d / "pts.csv").write_text("x,y,z\n0,0,0\n20,10,-0.25\n0,0,50\n")
    (d / "off.csv").write_text("0,0,50\n10,10,60\n")
    (d / "empty.stl").write_text("solid empty\nendsolid empty\n")
    two = SensorLayout(("A", "B", "C"), np.zeros((3, 3)), np.tile([0, 0, 1.0], (3, 1)))
    save_layout(two, d / "three.toml")
    txt = (d / "three.toml").read_text()
    (d / "two.toml").write_text(txt[: txt.rindex("[[sensors]]")])
    return d


def _invoke(args):
    from cli.main import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_cli_json_summary_and_per_point(files, tmp_path):
    out = tmp_path / "pp.json"
    r = _invoke(["normals", files / "cyl.stl", "--layout", files / "t6.toml", "--points", files / "pts.csv",
                 "--json", "--out", out, "--tilt-deg", "2", "--noise-mm", "0.005"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    for m in ("plane", "sphere"):
        assert set(s[m]) >= {"max_deg", "mean_deg", "std_deg"}
        assert s[m]["n"] == 2
    assert s["recommendation"]["method"] in ("plane", "sphere")
    assert s["status"]["off_panel"] == 1
    rows = json.loads(out.read_text())
    assert [row["status"] for row in rows] == ["ok", "ok", "off_panel"]
    assert rows[2]["plane_err_deg"] is None
    assert rows[2]["detail"].endswith("mm from the panel")


def test_cli_same_seed_same_bytes(files, tmp_path):
    outs = []
    for k in range(2):
        o = tmp_path / f"o{k}.csv"
        r = _invoke(["normals", files / "cyl.stl", "--layout", files / "t6.toml", "--grid", "40", "--seed", "3",
                     "--noise-mm", "0.01", "--out", o])
        assert r.exit_code == 0, r.output
        outs.append(o.read_bytes())
    assert outs[0] == outs[1]


@pytest.mark.parametrize("args, match", [
    (["empty.stl", "--layout", "t6.toml", "--grid", "20"], "empty"),
    (["cyl.stl", "--layout", "two.toml", "--grid", "20"], "at least 3 sensors"),
    (["cyl.stl", "--layout", "t6.toml", "--points", "off.csv"], "no drilling point could be measured"),
    (["cyl.stl", "--layout", "t6.toml"], "exactly one of --points"),
    (["cyl.stl", "--layout", "t6.toml", "--grid", "20", "--engine", "optix"], "engine must be"),
    (["missing.stl", "--layout", "t6.toml", "--grid", "20"], "missing.stl"),
])
def test_cli_fatal_errors_one_line_exit_2_no_output(files, tmp_path, args, match):
    out = tmp_path / "never.csv"
    full = ["normals"] + [files / a if a.endswith((".stl", ".toml", ".csv")) else a for a in args] + ["--out", out]
    r = _invoke(full)
    assert r.exit_code == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and match in lines[0]
    assert not out.exists()
    assert "Traceback" not in r.output


def test_cli_plot(files, tmp_path):
    png = tmp_path / "map.png"
    r = _invoke(["normals", files / "cyl.stl", "--layout", files / "t6.toml", "--grid", "30", "--plot", png, "--no-loop"])
    assert r.exit_code == 0, r.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


REAL = __import__("pathlib").Path(__file__).resolve().parents[1] / "data" / "meshes"


def _ran(r) -> dict:
    """The JSON of a run that ran: exit 0 when its verdict passed, 1 when it failed (docs/cli.md)."""
    assert r.exit_code in (0, 1), r.output
    s = json.loads(r.stdout)
    assert r.exit_code == (0 if s["verdict"]["passed"] else 1)
    return s


def test_cli_unitless_mesh_warns_before_it_fails_and_runs_with_units(files):
    """trimesh's cylinder.stl is 2 x 2 x 8 units and says nothing of its unit: taken as mm it
    is too small for the head; the unit warning comes first, then the error; --units m runs."""
    r = _invoke(["normals", REAL / "trimesh_cylinder.stl", "--layout", files / "t6.toml", "--grid", "1", "--no-loop"])
    assert r.exit_code == 2
    lines = r.stderr.strip().splitlines()
    assert lines[0].startswith("warning: ") and "is it in m or inch? give --units" in lines[0]
    assert "assumed" in lines[0] and lines[-1].startswith("error: ") and "--units" in lines[-1]
    # under -q the warning is silent, so the error repeats the unit doubt in full
    r = _invoke(["-q", "normals", REAL / "trimesh_cylinder.stl", "--layout", files / "t6.toml", "--grid", "1", "--no-loop"])
    assert r.exit_code == 2 and len(r.stderr.strip().splitlines()) == 1
    assert r.stderr.startswith("error: ") and "is it in m or inch? give --units" in r.stderr and "as m: " in r.stderr
    r = _invoke(["normals", REAL / "trimesh_cylinder.stl", "--layout", files / "t6.toml", "--grid", "100",
                 "--no-loop", "--units", "m", "--json"])
    s = _ran(r)
    assert s["info"]["units"].startswith("m (--units") and s["status"]["ok"] > 0 and s["grid_dropped"] > 0
    assert "warning" not in r.stderr


def test_cli_units_from_the_file_name_and_bad_units(files):
    from metrology.panel.mesh import load_panel

    p = load_panel(REAL / "trimesh_counter.unitsmm.ply")
    assert p.units == "mm (from the file name (unitsmm))" and not p.warnings
    r = _invoke(["normals", REAL / "trimesh_cylinder.stl", "--layout", files / "t6.toml", "--grid", "1", "--units", "km"])
    assert r.exit_code == 2 and "units must be one of mm, cm, m, in, got 'km'" in r.stderr


def test_cli_a_public_closed_wing(files):
    """TCAD's wing.stl (940 triangles, 177 x 100 units, no unit): as mm every grid point's
    footprint touches a crease (one line naming the footprint, exit 2); as cm a 1.8 m wing
    section: points measured, the nodes by the trailing edge and tip left out, no loop lost."""
    wing = REAL / "tcad_wing.stl"
    r = _invoke(["normals", wing, "--layout", files / "t6.toml", "--grid", "5", "--no-loop"])
    assert r.exit_code == 2 and r.stderr.startswith("error: ") and "footprint" in r.stderr
    r = _invoke(["normals", wing, "--layout", files / "t6.toml", "--grid", "50", "--tilt-deg", "2", "--seed", "1",
                 "--units", "cm", "--json"])
    s = _ran(r)
    from metrology.panel.edges import BOUNDARY
    from metrology.panel.mesh import load_panel

    assert not (load_panel(wing, "cm").edges().kind == BOUNDARY).any()  # closed: creases only
    assert s["status"]["ok"] > 300 and s["grid_dropped"] > 100
    assert s["plane"]["final_max_deg"] < 2.0  # every attitude loop ends near the normal (none lost)


def test_cli_beams_smooth_is_said_and_a_bad_value_is_one_line(files):
    args = ["normals", files / "cyl.stl", "--layout", files / "t6.toml", "--points", files / "pts.csv", "--no-loop"]
    r = _invoke([*args, "--beams", "smooth", "--json"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["info"]["beams"].startswith("smooth: Phong")
    r = _invoke([*args, "--beams", "smooth"])
    assert "beams hit the smooth surface the mesh tessellates" in r.stdout
    r = _invoke([*args, "--beams", "phong"])
    assert r.exit_code == 2 and r.stderr.strip() == "error: beams must be facets or smooth, got 'phong'"

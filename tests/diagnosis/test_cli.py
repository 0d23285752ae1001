"""metro simulate and metro diagnose through the CLI."""

from __future__ import annotations

import json
import re

from scipy import stats
from metrology.sim.synth import typical_layouts

from .helpers import PLANE

def test_cli_simulate_then_diagnose(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app
    from metrology.io.layout import save_layout

    nominal, _ = typical_layouts()
    save_layout(nominal, tmp_path / "layout.toml")
    (tmp_path / "plane.json").write_text(json.dumps({"normal": PLANE.normal.tolist(), "offset": PLANE.offset}))
    runner = CliRunner()
    r = runner.invoke(app, ["simulate", "--layout", str(tmp_path / "layout.toml"), "--plane",
                            str(tmp_path / "plane.json"), "--out", str(tmp_path / "x.csv"), "--effect", "outliers",
                            "--sensor", "L4", "--size", "0.1", "--poses", "60", "--seed", "3"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["diagnose", str(tmp_path / "x.csv"), "--plane", str(tmp_path / "plane.json"), "--layout",
                            str(tmp_path / "layout.toml"), "--json", "--folds", "3", "--report", str(tmp_path / "d.html")])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout)  # stderr: the "report: FILE" line
    assert out["cause"] == "outliers" and out["sensors"] == ["L4"]
    assert out["datum_form"] is None
    assert {"heldout", "candidates", "extended", "discrepancy"} <= set(out)
    assert all("p_heldout" in c and "p_insample" in c for c in out["candidates"])
    # --report FILE.html: one self-contained page, the cause first, the residual figures
    # embedded: the overview grid where a cell of the structure table carries structure (a
    # gross reading leaves none), the held-out residuals before and after the cause
    # (--report DIR, the PNGs, runs in the demo's test)
    from metrology.diagnosis.stats import Trend
    from metrology.report.diagnose import structured_cells
    from tests.report.test_html import check_page

    held = out["discrepancy"]["measured_heldout_normal_deg"]
    assert held < 0.5  # the cause first, then the held-out normal against the tolerance
    text = check_page(tmp_path / "d.html", [tmp_path / "x.csv", tmp_path / "layout.toml"],
                      1 + bool(structured_cells({k: {s: Trend(**c) for s, c in row.items()}
                                                 for k, row in out["structure"].items()})),
                      f"cause: outliers on L4; normal within tolerance ({held:.4f} vs 0.5 deg)")
    # the fit report's chi-square and dof are of the same readings (L4's): with the simulated
    # noise at the stated level, chi-square over dof lies in the chi-square distribution's band
    stat = dict(re.findall(r"^ +(# data points|# variables|chi-square) += ([0-9.e+-]+)$", text, re.M))
    ndata, nvarys, chi2 = int(stat["# data points"]), int(stat["# variables"]), float(stat["chi-square"])
    assert ndata == 60 and 6 <= nvarys < 60
    assert stats.chi2.ppf(0.0005, ndata - nvarys) < chi2 < stats.chi2.ppf(0.9995, ndata - nvarys), stat


def test_cli_errors_are_one_line_exit_2(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app

    runner = CliRunner()
    r = runner.invoke(app, ["diagnose", str(tmp_path / "nope.csv"), "--plane", str(tmp_path / "p.json"),
                            "--layout", str(tmp_path / "l.toml")])
    assert r.exit_code == 2
    assert "error:" in r.output and "Traceback" not in r.output
    nominal, _ = typical_layouts()
    from metrology.io.layout import save_layout

    save_layout(nominal, tmp_path / "layout.toml")
    (tmp_path / "plane.json").write_text(json.dumps({"normal": PLANE.normal.tolist(), "offset": PLANE.offset}))
    r = runner.invoke(app, ["simulate", "--layout", str(tmp_path / "layout.toml"), "--plane",
                            str(tmp_path / "plane.json"), "--out", str(tmp_path / "x.csv"), "--effect", "scale",
                            "--sensor", "L9", "--size", "0.001"])
    assert r.exit_code == 2 and "L9" in r.output
    assert not (tmp_path / "x.csv").exists()


def test_cli_simulate_writes_a_datum_cloud_that_diagnose_reads(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app
    from metrology.io.clouds import read_cloud
    from metrology.io.layout import save_layout

    nominal, _ = typical_layouts()
    save_layout(nominal, tmp_path / "layout.toml")
    (tmp_path / "plane.json").write_text(json.dumps({"normal": PLANE.normal.tolist(), "offset": PLANE.offset}))
    runner = CliRunner()
    base = ["simulate", "--layout", str(tmp_path / "layout.toml"), "--plane", str(tmp_path / "plane.json"),
            "--out", str(tmp_path / "x.csv"), "--effect", "plane_form", "--size", "0.01", "--seed", "5"]
    r = runner.invoke(app, base + ["--cloud", str(tmp_path / "datum.xyz")])
    assert r.exit_code == 2 and "datum.xyz" in r.output and ".ply" in r.output
    assert not (tmp_path / "x.csv").exists()
    r = runner.invoke(app, base + ["--cloud", str(tmp_path / "datum.ply")])
    assert r.exit_code == 0, r.output
    pts = read_cloud(tmp_path / "datum.ply")
    assert pts.shape == (4000, 3)
    r = runner.invoke(app, ["diagnose", str(tmp_path / "x.csv"), "--plane", str(tmp_path / "datum.ply"), "--layout",
                            str(tmp_path / "layout.toml"), "--folds", "3"])
    assert r.exit_code == 0, r.output
    assert "cause: plane_form" in r.output and "points, under the spots)" in r.output and "RMS in the base residuals" in r.output
    assert "the readings' plane_form" in r.output  # agrees or DISAGREES: the verdict is tested in the library

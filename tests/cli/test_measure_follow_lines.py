"""metro measure --follow: a last line cut inside a field is not measured (noted), and each hole's JSON
line carries what the table has (issue 51, item 10)."""

import json

from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path

runner = CliRunner()
TABLE6 = str(data_path("measured", "nominal.toml"))
WING = str(data_path("panels", "wing.stl"))
HOLES = str(data_path("panels", "wing.holes.csv"))


def _log(tmp_path):
    log = tmp_path / "wing.csv"
    r = runner.invoke(app, ["simulate-log", "--panel", WING, "--points", HOLES, "--holes", "12", "--seed", "4",
                            "--layout", TABLE6, "--true-layout", TABLE6, "--out", str(log)])
    assert r.exit_code == 0, r.output
    return log.read_text(encoding="utf-8")


def _follow(text, *extra):
    r = runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow", *extra], input=text)
    holes = [json.loads(x) for x in r.stdout.splitlines() if '"hole_id"' in x and '"line"' in x]
    return r, holes


def test_a_last_line_cut_inside_a_field_is_not_measured(tmp_path):
    text = _log(tmp_path)
    whole, holes = _follow(text)
    assert whole.exit_code == 0, whole.output
    assert len(holes) == 12
    cut = text.rstrip("\n")[:-3]  # the last line cut inside its last field, no newline
    r, cut_holes = _follow(cut)
    assert r.exit_code == 0, r.output
    assert len(cut_holes) == 11 and [h["hole_id"] for h in cut_holes] == [h["hole_id"] for h in holes[:11]]
    summary = json.loads(r.stdout.splitlines()[-1])["summary"]
    assert len(summary["notes"]) == 1 and "ends without a newline" in summary["notes"][0]
    assert "warning:" in r.output and "not measured" in r.output
    assert sum(summary["counts"].values()) == 11


def test_each_holes_line_carries_the_tables_columns(tmp_path):
    text = _log(tmp_path)
    r, holes = _follow(text, "--panel", WING, "--points", HOLES)
    assert r.exit_code in (0, 1), r.output
    h = holes[0]
    for k in ("time", "cell", "cad_offset_mm", "normal_vs_cad_deg", "panel_misfit_per_mm", "panel_misfit_z",
              "k1_per_mm", "correction_deg"):
        assert k in h, k
    assert h["time"].endswith("Z") and h["time"][:4] == "2026" and h["cell"] == "C1"
    assert isinstance(h["cad_offset_mm"], float)

"""Another panel's hole table whose hole_ids the log shares (H0001 is every table's first hole): the log's
commanded positions lie far from the table's points in every unit; refused in one line, exit 2, nothing written
(issue 51, item 4's neighbour: before, a run on it judged holes on a surface they were not drilled on, or
counted them "drilled angle not known: re-inspect")."""

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from metrology.io.panel_units import check_panel_units

runner = CliRunner()
TABLE6 = str(data_path("measured", "nominal.toml"))
WING = str(data_path("panels", "wing.holes.csv"))


def test_the_rule_refuses_positions_no_unit_brings_to_their_holes():
    """The rule alone: the positions 450 mm off their holes, the table in mm (its spacing, 200 mm, plausible):
    no unit explains it, refused naming the table's doubt; 50 mm off (the stand-off): let through."""
    g = np.stack(np.meshgrid(np.arange(0, 2001, 200.0), np.arange(0, 1001, 200.0)), -1).reshape(-1, 2)
    T = np.c_[g, np.zeros(len(g))]
    ok = dict(footprint_mm=26.6, standoff_mm=50.0, table_points=T, names="t.csv", log_name="log.csv")
    assert check_panel_units(**ok, pose_points=T + [0, 0, 50.0]) is None
    line = check_panel_units(**ok, pose_points=T + [450.0, 0, 50.0])
    assert line is not None and line.startswith("log.csv: the log's commanded positions lie a median 453 mm")
    assert "no unit brings them closer: is it this panel's table" in line


@pytest.fixture(scope="module")
def wing_log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("wrong_table")
    log = folder / "wing.csv"
    r = runner.invoke(app, ["simulate-log", "--panel", "wing", "--points", WING, "--holes", "30", "--seed", "5",
                            "--layout", TABLE6, "--true-layout", TABLE6, "--out", str(log)])
    assert r.exit_code == 0, r.output
    return folder, str(log)


def test_another_panels_table_sharing_the_hole_ids_is_refused(wing_log):
    """The wing's log against a table of the same hole_ids 400 mm away (another panel's): exit 2, one line naming
    the log, the gap and the doubt; no output written. The wing's own table: measured."""
    folder, log = wing_log
    other = folder / "other.holes.csv"
    with open(WING, newline="") as fh:
        rows = list(csv.reader(fh))
    with open(other, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(rows[0])
        w.writerows([r[0], f"{float(r[1]) + 400.0:.6f}", *r[2:]] for r in rows[1:])
    out = folder / "o.csv"
    r = runner.invoke(app, ["measure", log, "--layout", TABLE6, "--points", str(other), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {log}: the log's commanded positions lie a median 4")
    assert "is it this panel's table" in lines[0]
    assert not out.exists()
    r = runner.invoke(app, ["measure", log, "--layout", TABLE6, "--points", WING, "--out", str(out)])
    assert r.exit_code == 0, r.output

"""Without the panel, a layout that is not the head's calibration (here the nominal of a head drawn 0.2 mm / 0.2 deg off
it) gives most holes a redundant misfit that rule 2b covers, as a curved panel within the radius bound does; the run
cannot tell the two apart, and its rule 2b check line says both, naming the layout, when over MISFIT_SHARE of the holes
are rule 2b's (the walk of issue 51, round 7: the run named one sensor's offset in every hole, never the layout). A
head measured with its own calibration keeps the line as it was."""

import json

import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from metrology.jobs.measure_report import MISFIT_SHARE

runner = CliRunner()
NOMINAL = str(data_path("measured", "nominal.toml"))
HINT = "a layout that is not this head's calibration"


def _rule_2b(folder, layout_error_mm, true_layout=None):
    log = folder / f"log{layout_error_mm}.csv"
    args = ["simulate-log", "--layout", NOMINAL, "--holes", "300", "--seed", "3", "--out", str(log)]
    args += ["--true-layout", true_layout] if true_layout else ["--layout-error-mm", str(layout_error_mm)]
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["measure", str(log), "--layout", NOMINAL, "--out", str(folder / f"r{layout_error_mm}.csv"),
                            "--json"])
    assert r.exit_code in (0, 1), r.output
    d = json.loads(r.stdout)
    (line,) = [c for c in d["verdict"]["checks"] if "rule 2b" in c["name"]]
    return line, d["curvature"]["one_sensor_offset_holes"], d["holes"]


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("layout_hint")


def test_most_holes_on_rule_2b_name_the_layout(folder):
    line, n, holes = _rule_2b(folder, 0.2)
    assert n > MISFIT_SHARE * holes
    assert HINT in line["name"] and "--panel/--points" in line["name"]


def test_the_heads_own_layout_is_not_named(folder):
    line, n, holes = _rule_2b(folder, 0.0, true_layout=NOMINAL)
    assert n <= MISFIT_SHARE * holes
    assert HINT not in line["name"]

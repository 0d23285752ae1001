"""Exit codes by verdict, one rule for every command (docs/cli.md): 0 ran and passed, 1 ran and
the verdict failed, 2 bad input or usage; every ``--json`` carries the ``verdict`` object.

One passing and one failing case per command. The commands that judge nothing (``simulate``,
``plan``, ``reproduce``, ``version``) pass with no checks; their failing case is bad input (2).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import DATA_DIR
from tests.calibration.helpers import CAL, NOMINAL, PLANE, TRUTH, VAL, export_rows, write_rows

runner = CliRunner()
H = DATA_DIR / "hidden"


def _run(args, code, stdin=None) -> dict:
    """Run ``args --json``: its exit code is ``code`` and the verdict's; returns the verdict."""
    r = runner.invoke(app, [*map(str, args), "--json"], input=stdin)
    assert r.exit_code == code, r.output
    v = json.loads(r.stdout)["verdict"]
    assert set(v) == {"passed", "checks"} and v["passed"] is (code == 0)
    for c in v["checks"]:
        assert set(c) == {"name", "value", "limit", "unit", "passed", "gate"}
    assert v["passed"] == all(c["passed"] for c in v["checks"] if c["gate"])
    return v


def _failed(v) -> list:
    return [c["name"] for c in v["checks"] if c["gate"] and not c["passed"]]


@pytest.fixture(scope="module")
def bowed(tmp_path_factory):
    """A plate bowed by 50 µm (analytic paraboloid, 5 µm noise): P-V about 0.06 mm."""
    rng = np.random.default_rng(7)
    u, v = rng.uniform(-100.0, 100.0, (2, 1500))
    xyz = np.column_stack([u, v, 2.5e-6 * (u**2 + v**2) + rng.normal(0.0, 0.005, u.size)])
    path = tmp_path_factory.mktemp("bowed") / "bowed.xyz"
    np.savetxt(path, xyz, fmt="%.6f")
    return path


def test_fit_plane_judges_flatness_only_when_given(bowed):
    v = _run(["fit-plane", bowed], 0)  # no tolerance: what was found is information
    assert not any(c["gate"] for c in v["checks"])
    assert {c["name"].split(":")[0] for c in v["checks"]} == {"form", "scan"}
    v = _run(["fit-plane", bowed, "--flatness-mm", "0.5"], 0)
    v = _run(["fit-plane", bowed, "--flatness-mm", "0.02"], 1)
    assert _failed(v) == ["flatness tolerance: P-V of the inliers"]
    c = v["checks"][0]
    assert c["limit"] == 0.02 and c["unit"] == "mm" and c["value"] > 0.02


@pytest.fixture(scope="module")
def short_export(tmp_path_factory):
    return write_rows(tmp_path_factory.mktemp("cal") / "cal.csv", export_rows(CAL)[:17])  # 16 poses: fast


def test_calibrate_gates_on_targets_the_user_set_only(short_export):
    base = ["calibrate", short_export, "--plane", PLANE, "--layout", NOMINAL]
    v = _run(base, 0)  # the default target and the model adequacy are information
    assert not any(c["gate"] for c in v["checks"])
    kinds = {c["name"].split(":")[0] for c in v["checks"]}
    assert kinds == {"model adequacy", "precision target", "datum"}  # datum: the plane taken as exact (information)
    assert any(not c["passed"] for c in v["checks"])  # information beyond its limit does not fail
    v = _run([*base, "--target-mm", "1", "--target-deg", "1"], 0)
    assert [c["limit"] for c in v["checks"] if c["gate"]] == [1.0, 1.0]
    v = _run([*base, "--target-mm", "0.001"], 1)
    assert "precision target: zero points, largest 1σ" in _failed(v)


def test_validate_fails_out_of_the_drilling_tolerance():
    base = ["validate", VAL, "--plane", PLANE]
    v = _run([*base, "--layout", TRUTH], 0)
    c = v["checks"][0]
    assert c["name"] == "drilling tolerance: max normal deviation" and c["limit"] == 0.5 and c["unit"] == "deg"
    v = _run([*base, "--layout", NOMINAL], 1)  # the nominal layout: 0.62 deg
    assert _failed(v) == ["drilling tolerance: max normal deviation"] and v["checks"][0]["value"] > 0.5


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    """Two 40-pose exports from the forward simulator: nothing hidden, and outliers on L4."""
    tmp = tmp_path_factory.mktemp("sim")
    out = {}
    for name, extra in (("clean", []), ("outliers", ["--effect", "outliers", "--sensor", "L4", "--size", "0.1"])):
        out[name] = tmp / f"{name}.csv"
        v = _run(["simulate", "--layout", H / "layout.toml", "--plane", H / "plane.json", "--out", out[name],
                  "--poses", "40", "--seed", "3", *extra], 0)
        assert v["checks"] == []
    return out


def test_diagnose_fails_on_a_cause_only_with_fail_on_cause(exports):
    base = ["--plane", H / "plane.json", "--layout", H / "layout.toml", "--folds", "2"]
    v = _run(["diagnose", exports["clean"], *base, "--fail-on-cause"], 0)
    assert v["checks"][1]["name"] == "cause found: none" and v["checks"][1]["gate"]
    v = _run(["diagnose", exports["outliers"], *base, "--fail-on-cause"], 1)
    assert _failed(v) == ["cause found: outliers"]


def test_a_cause_is_information_without_fail_on_cause():
    """The one function that reads a Diagnosis for the exit code (its ``to_dict()`` only)."""
    from metrology.report.verdicts import diagnosis_verdict

    class Found:
        def to_dict(self):
            return {"cause": "drift", "causes": [{"cause": "drift"}],
                    "discrepancy": {"measured_heldout_normal_deg": 0.2}}

    v = diagnosis_verdict(Found())
    assert v.passed and [c.gate for c in v.checks] == [True, False] and v.checks[1].value == 1
    assert not diagnosis_verdict(Found(), fail_on_cause=True).passed
    assert not diagnosis_verdict(Found(), tolerance_deg=0.1).passed  # 0.2 deg held out: out of tolerance


def test_normals_fails_out_of_tolerance():
    base = ["normals", DATA_DIR / "panel_cyl800.stl", "--layout", DATA_DIR / "layout_table6.toml", "--grid", "60",
            "--no-loop"]
    v = _run(base, 0)
    assert [c["gate"] for c in v["checks"]].count(True) == 1
    v = _run([*base, "--tolerance-deg", "0.0001"], 1)
    assert len(_failed(v)) == 1 and _failed(v)[0].startswith("drilling tolerance: micro-")


def test_demo_runs_every_step_and_fails_when_one_verdict_does(tmp_path, monkeypatch):
    import metrology.jobs.demo as demo

    steps = (("1. version", "version"),
             ("2. validate", f"validate {VAL} --plane {PLANE} --layout {{fx}}/measured/nominal.toml"),
             ("3. version", "version"))
    monkeypatch.setattr(demo, "DEMO_STEPS", steps[::2])
    v = _run(["demo", "--out", tmp_path / "a"], 0)
    assert [c["name"] for c in v["checks"]] == ["step version: exit code"] * 2
    monkeypatch.setattr(demo, "DEMO_STEPS", steps)
    r = runner.invoke(app, ["demo", "--out", str(tmp_path / "b"), "--json"])
    assert r.exit_code == 1, r.output
    out = json.loads(r.stdout)
    assert [s["exit_code"] for s in out["steps"]] == [0, 1, 0]  # the step after the failing one ran
    assert out["steps"][1]["result"]["verdict"]["passed"] is False
    assert _failed(out["verdict"]) == ["step validate: exit code"]


@pytest.mark.parametrize("args", [
    ["plan", "--layout", NOMINAL, "--plane", DATA_DIR / "measured" / "datum.ply", "--poses", "6", "--candidates", "200"],
    ["reproduce", "--poses", "20", "--figures", "-"],
    ["version"],
])
def test_commands_that_judge_nothing_pass_with_no_checks(args):
    assert _run(args, 0) == {"passed": True, "checks": []}


@pytest.mark.parametrize("args", [
    ["plan", "--layout", NOMINAL, "--plane", "nope.ply", "--poses", "6"],
    ["reproduce", "--standoff-mm", "70,30"],
    ["simulate", "--layout", "nope.toml", "--plane", PLANE, "--out", "x.csv"],
    ["validate", VAL, "--plane", PLANE, "--layout", "nope.toml"],
    ["calibrate", CAL, "--plane", PLANE, "--layout", NOMINAL, "--target-mm", "-1"],
    ["fit-plane", "nope.ply"],
    ["version", "--bogus"],
])
def test_bad_input_is_exit_2_one_error_line(args, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, [*map(str, args), "--json"])
    assert r.exit_code == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert lines[0].startswith("error: ") and len(lines) <= 2, r.stderr


@pytest.mark.parametrize("args", [
    ["simulate", "--layout", TRUTH, "--plane", PLANE, "--out", "{tmp}/s.csv"],
    ["simulate-log", "--holes", "200", "--out", "{tmp}/log.csv"],
    ["reproduce", "--poses", "20", "--figures", "-"],
])
def test_commands_that_judge_nothing_print_their_verdict_line(tmp_path, args):
    r = runner.invoke(app, [str(a).replace("{tmp}", str(tmp_path)) for a in args])
    assert r.exit_code == 0, r.output
    assert "verdict: passed (exit code 0)" in r.output, r.output

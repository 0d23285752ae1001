"""CLI of the core: reproduce, --help without heavy imports, determinism."""

import json
import subprocess
import sys

import numpy as np
from typer.testing import CliRunner

from cli.main import app

runner = CliRunner()
SMALL = ["--poses", "30", "--figures", "-", "--json"]


def test_help_does_not_import_heavy_libraries():
    code = (
        "import sys; from typer.testing import CliRunner; from cli.main import app; "
        "r = CliRunner().invoke(app, ['--help']); assert r.exit_code == 0, r.output; "
        "heavy = [m for m in ('open3d', 'trimesh', 'scipy', 'matplotlib', 'filterpy') if m in sys.modules]; "
        "print(','.join(heavy))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", f"heavy modules imported by --help: {out.stdout}"


def test_reproduce_json_has_the_tables():
    r = runner.invoke(app, ["reproduce", *SMALL])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert set(s["table4"]) == {"before", "method1", "ekf_paper", "ekf", "iekf", "lsq", "true"}
    t4 = s["table4"]
    # calibration helps, and the batch estimator is within 2x of the truth floor
    assert t4["lsq"]["mean_deg"] < 0.2 * t4["before"]["mean_deg"]
    assert t4["lsq"]["mean_deg"] < 2 * t4["true"]["mean_deg"]
    assert len(s["table3"]["n_converged_trial1"]) == 4
    assert np.allclose(s["table1"]["theoretical"][:3], [0.0173, -0.3071, 0.9515], atol=1e-4)


def test_reproduce_is_deterministic():
    a = runner.invoke(app, ["reproduce", *SMALL, "--seed", "7"])
    b = runner.invoke(app, ["reproduce", *SMALL, "--seed", "7"])
    c = runner.invoke(app, ["reproduce", *SMALL, "--seed", "8"])
    assert a.exit_code == 0 and a.stdout == b.stdout and a.stdout != c.stdout


def test_reproduce_experiment_layout_and_trials(tmp_path):
    r = runner.invoke(app, ["reproduce", "--layout", "experiment", "--trials", "2", "--poses", "30",
                            "--figures", str(tmp_path / "figs")])
    assert r.exit_code == 0, r.output
    assert "Table 4 analogue" in r.stdout and "+-" in r.stdout
    for name in ("figure7_ekf_convergence.png", "figure8_angular_deviation.png"):
        assert (tmp_path / "figs" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_reproduce_bad_input_is_one_line_exit_2(tmp_path):
    for args, msg in [(["--layout", "bogus"], "layout must be"), (["--standoff-mm", "60,40"], "standoff"),
                      (["--standoff-mm", "60"], "expected two numbers MIN,MAX in mm")]:
        r = runner.invoke(app, ["reproduce", *args, "--figures", str(tmp_path / "never")])
        assert r.exit_code == 2
        assert msg in r.output and len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "never").exists()


def test_demo_runs_from_an_empty_folder_on_the_shipped_data(tmp_path, monkeypatch):
    """No option, an empty current folder: the shipped data, outputs in ./metro-demo."""
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, ["demo"])
    assert r.exit_code == 0, r.output
    for step in ("fit-plane", "calibrate", "validate", "diagnose", "normals"):
        assert f"$ metro {step}" in r.output
    assert "cause:" in r.output and "recommendation:" in r.output
    # the round trip: diagnose --out, calibrate --layout, measure --layout removing the term from every reading
    assert "--out" in r.output and "--layout" in r.output
    assert "the head's terms (drift.L3@temp), removed from every reading" in r.output
    for name in ("plane.json", "calibrated.toml", "validation.png", "panel_errors.png", "diagnose/residuals_base.png",
                 "diagnose/residuals_named.png", "calibration/convergence.png"):
        assert (tmp_path / "metro-demo" / name).stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metro-demo"]


def test_demo_never_writes_into_a_used_folder(tmp_path):
    from metrology.jobs.demo import new_output_dir

    base = tmp_path / "metro-demo"
    assert new_output_dir(base) == base
    base.mkdir()
    assert new_output_dir(base) == base  # empty: used as it is
    (base / "plane.json").write_text("{}")
    assert new_output_dir(base) == tmp_path / "metro-demo-2"


def test_demo_without_fixtures_is_one_line_exit_2(tmp_path):
    r = runner.invoke(app, ["demo", "--fixtures", str(tmp_path / "nope"), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "fixtures not found" in r.output and len(r.output.strip().splitlines()) == 1


def test_version_help_and_bare_metro():
    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0 and r.output.startswith("metro ")
    for args in (["-h"], ["--help"], []):
        r = runner.invoke(app, args)
        assert r.exit_code == 0 and "fit-plane" in r.output and "calibrate" in r.output, args
    r = runner.invoke(app, ["calibrate", "-h"])
    assert r.exit_code == 0 and "--plane" in r.output

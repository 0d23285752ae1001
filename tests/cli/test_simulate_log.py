"""``metro simulate-log``: exit 0 with the files, exit 2 with one line on a bad value, nothing written."""

import json
import subprocess
import sys

import pyarrow.csv as pcsv
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path

runner = CliRunner()


def test_csv_log_and_truth_exit_0(tmp_path):
    out = tmp_path / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--out", str(out), "--holes", "3000", "--cells", "2", "--panel", "sphere",
                            "--radius-mm", "800", "--shift", "C1/L2:0.05@1000", "--drift", "L3:0.01", "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["schema"] == "metro.simulate-log/1" and s["holes"] == 3000 and s["format"] == "csv"
    assert s["truth"] == str(tmp_path / "log.truth.csv")
    assert pcsv.read_csv(out).num_rows == 3000 and pcsv.read_csv(tmp_path / "log.truth.csv").num_rows == 3000
    assert s["spec"]["shifts"][0] == {"sensor": "L2", "size_mm": 0.05, "hole": 999, "cell": "C1"}


def test_parquet_folder_and_same_seed_same_bytes(tmp_path):
    args = ["simulate-log", "--holes", "2000", "--seed", "3", "--truth"]
    for name in ("a", "b"):
        r = runner.invoke(app, [*args, str(tmp_path / f"{name}.truth.csv"), "--out", str(tmp_path / name)])
        assert r.exit_code == 0, r.output
        assert "wrote" in r.stdout and "holes" in r.stdout
    fa = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*.parquet"))
    assert fa and fa == sorted(p.relative_to(tmp_path / "b") for p in (tmp_path / "b").rglob("*.parquet"))
    assert all((tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes() for f in fa)
    assert (tmp_path / "a.truth.csv").read_bytes() == (tmp_path / "b.truth.csv").read_bytes()


@pytest.mark.parametrize("args, msg", [
    (["--angle-deg", "5,1"], "--angle-deg 5,1"),
    (["--angle-deg", "x"], "MIN,MAX"),
    (["--drift", "L2:fast"], "rate 'fast' is not a number"),
    (["--drift", "L9:0.01"], "'L9': not in the layout"),
    (["--shift", "L2:0.05"], "SENSOR:MM@HOLE"),
    (["--shift", "L2:0.05@0"], "1 or more"),
    (["--panel", "cone"], "expected one of flat, sphere, cylinder"),
    (["--panel", "sphere"], "needs a radius"),
    (["--panel", "sphere", "--radius-mm", "200"], "0.9 R"),
    (["--holes", "0"], "holes >= cells"),
    (["--layout", str(data_path("layout_table2.toml"))], "give --noise-mm"),
    (["--gross-rate", "2"], "probability"),
])
def test_bad_values_are_one_line_exit_2_and_write_nothing(tmp_path, args, msg):
    out = tmp_path / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--out", str(out), "--holes", "100", *args])
    assert r.exit_code == 2, r.output
    assert msg in r.output and len(r.output.strip().splitlines()) == 1 and r.output.startswith("error:")
    assert list(tmp_path.iterdir()) == []


def test_no_truth_writes_the_log_alone(tmp_path):
    r = runner.invoke(app, ["simulate-log", "--out", str(tmp_path / "log.csv"), "--holes", "100", "--no-truth"])
    assert r.exit_code == 0, r.output
    assert [p.name for p in tmp_path.iterdir()] == ["log.csv"] and "truth: not written" in r.stdout
    r = runner.invoke(app, ["simulate-log", "--out", str(tmp_path / "b.csv"), "--no-truth", "--truth",
                            str(tmp_path / "t.csv")])
    assert r.exit_code == 2 and "exclude each other" in r.output


def test_an_existing_log_folder_is_never_written_over(tmp_path):
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "keep.parquet").write_bytes(b"x")
    r = runner.invoke(app, ["simulate-log", "--out", str(tmp_path / "logs"), "--holes", "100"])
    assert r.exit_code == 2 and "not an empty folder" in r.output
    assert [p.name for p in (tmp_path / "logs").iterdir()] == ["keep.parquet"]


def test_help_loads_no_pyarrow():
    code = ("import sys; from typer.testing import CliRunner; from cli.main import app; "
            "r = CliRunner().invoke(app, ['simulate-log', '--help']); assert r.exit_code == 0, r.output; "
            "print('pyarrow' in sys.modules, 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]

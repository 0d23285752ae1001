"""``metro plan``: the CSV round-trips through the export reader, and bad input is one line, exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.core.frames import matrix_from_quaternion
from metrology.io.data import DATA_DIR
from metrology.io.export import read_export

M = DATA_DIR / "measured"
runner = CliRunner()
BASE = ["plan", "--layout", str(M / "nominal.toml"), "--plane", str(M / "datum.ply"), "--poses", "12",
        "--candidates", "600"]


def test_csv_round_trips_through_the_export_reader(tmp_path):
    out = tmp_path / "poses.csv"
    r = runner.invoke(app, [*BASE, "--out", str(out), "--json"])
    assert r.exit_code == 0, r.output
    plan = json.loads(r.stdout)
    export = read_export(out)
    assert export.names == ("L1", "L2", "L3", "L4") and export.n_poses == 12
    assert np.all(np.isnan(export.d)) and len(set(export.pose_id)) == 12
    header = out.read_text().splitlines()[0]
    assert header == "pose_id,x,y,z,qw,qx,qy,qz,d_L1,d_L2,d_L3,d_L4"
    R = matrix_from_quaternion(export.quaternion)
    assert np.allclose(np.einsum("pij,pik->pjk", R, R), np.eye(3), atol=1e-9)
    # the file's tilts are the plan's: tool axis +z against the datum normal
    from metrology.calibration.dataset import load_plane

    plane, _ = load_plane(M / "datum.ply")
    tilt = np.degrees(np.arccos(np.clip(-R[:, :, 2] @ plane.normal, -1, 1)))
    assert tilt.max() <= plan["limits"]["tilt_max_deg"]
    assert plan["planned"]["log_det"] >= plan["random"]["log_det"]
    assert len(plan["planned"]["curve"]["k"]) == 12


@pytest.mark.parametrize("extra, words", [
    (["--poses", "3"], "need at least 5"),
    (["--standoff-mm", "50"], "--standoff-mm"),
    (["--standoff-mm", "60,40"], "MIN < MAX"),
    (["--tool-side", "up"], "--tool-side"),
    (["--tilt-max-deg", "0"], "--tilt-max-deg"),
    (["--margin-mm", "-1"], "--margin-mm"),
])
def test_bad_options_are_one_line_errors(tmp_path, extra, words):
    out = tmp_path / "p.csv"
    r = runner.invoke(app, [*BASE, *extra, "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], r.stderr
    assert not out.exists()


def test_a_plane_json_needs_an_extent_and_a_layout_needs_a_range(tmp_path):
    r = runner.invoke(app, ["plan", "--layout", str(M / "nominal.toml"), "--plane", str(M / "plane.json"), "--poses", "10"])
    assert r.exit_code == 2 and "extent" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = runner.invoke(app, ["plan", "--layout", str(DATA_DIR / "layout_table6.toml"), "--plane", str(M / "datum.ply"),
                            "--poses", "10", "--noise-mm", "0.003"])
    assert r.exit_code == 2 and "--range-mm" in r.stderr


@pytest.mark.parametrize("option", ["--out", "--plot"])
def test_an_output_that_names_a_folder_is_refused(tmp_path, option):
    for value, words in ((f"{tmp_path}/new.d/", "ends in a separator"), (str(tmp_path), "is a folder"),
                         (f"{tmp_path}/missing/p.csv", "does not exist")):
        r = runner.invoke(app, [*BASE, option, value])
        assert r.exit_code == 2, r.output
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"error: {option} ") and words in lines[0], r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []

"""Outputs other tools read: ``fit-plane --inliers/--outliers`` (PLY, read back by Open3D's
reader through metro's), ``--residuals`` (CSV or Parquet), ``validate --per-pose`` (CSV)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.clouds import read_cloud
from tests.calibration.helpers import NOMINAL, PLANE, TRUTH, VAL

runner = CliRunner()


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """A flat plate z = 0.2 x (known plane), 5 µm noise, and 30 points 1-3 mm off it (a clamp)."""
    rng = np.random.default_rng(11)
    u, v = rng.uniform(0.0, 200.0, (2, 1200))
    flat = np.column_stack([u, v, 0.2 * u + rng.normal(0.0, 0.005, u.size)])
    a, b = rng.uniform(0.0, 200.0, (2, 30))
    off = np.column_stack([a, b, 0.2 * a + rng.uniform(1.0, 3.0, 30)])
    path = tmp_path_factory.mktemp("plate") / "plate.xyz"
    np.savetxt(path, np.vstack([flat, off]), fmt="%.6f")
    return path, np.loadtxt(path)  # the points as the file holds them


def test_fit_plane_writes_inliers_outliers_and_residuals(plate, tmp_path):
    path, pts = plate
    r = runner.invoke(app, ["fit-plane", str(path), "--json", "--inliers", str(tmp_path / "in.ply"), "--outliers",
                            str(tmp_path / "out.ply"), "--residuals", str(tmp_path / "r.csv")])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    inl, outl = read_cloud(tmp_path / "in.ply"), read_cloud(tmp_path / "out.ply")
    assert len(inl) == d["n_inliers"] and len(inl) + len(outl) == len(pts)
    # the clamp's 30 points are outliers (with a few of the noise's tails, beyond 3 robust sigma)
    assert {tuple(p) for p in pts[-30:]} <= {tuple(p) for p in outl} and len(outl) < 30 + 10
    with open(tmp_path / "r.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["x", "y", "z", "residual_mm", "inlier"] and len(rows) == len(pts)
    res = np.array([float(row["residual_mm"]) for row in rows])
    xyz = np.array([[float(row[k]) for k in "xyz"] for row in rows])
    np.testing.assert_array_equal(xyz, pts)  # every point, in the file's order, exactly
    n = np.array(d["normal"])
    np.testing.assert_allclose(res, xyz @ n + d["offset"], atol=1e-12)
    # the plane z = 0.2 x: residuals of the clamp points are their height off it along the normal
    assert np.all(np.abs(res[-30:]) > 0.9 / np.sqrt(1.04)) and np.std(res[:-30]) < 0.006
    flags = np.array([int(row["inlier"]) for row in rows])
    assert flags.sum() == len(inl) and not flags[-30:].any()
    assert np.all(np.abs(res[:-30][flags[:-30] == 0]) < 0.05)  # the tails: near the plane all the same


def test_residuals_as_parquet(plate, tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    path, pts = plate
    r = runner.invoke(app, ["fit-plane", str(path), "--residuals", str(tmp_path / "r.parquet")])
    assert r.exit_code == 0, r.output
    t = pq.read_table(tmp_path / "r.parquet")
    assert t.column_names == ["x", "y", "z", "residual_mm", "inlier"] and t.num_rows == len(pts)
    np.testing.assert_array_equal(t.column("x").to_numpy(), pts[:, 0])


@pytest.mark.parametrize("option, name, words", [("--inliers", "in.pcd", "must be one of .ply"),
                                                 ("--residuals", "r.txt", "must be one of .csv, .parquet"),
                                                 ("--outliers", "nodir/o.ply", "does not exist")])
def test_a_bad_output_is_refused_before_any_work(plate, tmp_path, option, name, words):
    r = runner.invoke(app, ["fit-plane", str(plate[0]), option, str(tmp_path / name), "--out", str(tmp_path / "p.json")])
    assert r.exit_code == 2 and words in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "p.json").exists()


def test_validate_per_pose(tmp_path):
    out = tmp_path / "poses.csv"
    r = runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH), "--layout-before",
                            str(NOMINAL), "--per-pose", str(out), "--json", "--tolerance-deg", "0.01"])
    assert r.exit_code == 1, r.output  # some poses above 0.01 deg
    d = json.loads(r.stdout)
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["pose_id", "n_readings", "deviation_deg_before", "deviation_deg", "within_tolerance"]
    assert [row["pose_id"] for row in rows] == d["pose_id"]
    for row, n, after, before in zip(rows, d["n_readings"], d["layouts"]["layout"]["deviation_deg"],
                                     d["layouts"]["layout_before"]["deviation_deg"]):
        assert int(row["n_readings"]) == n
        if after is None:  # fewer than 3 readings: no normal
            assert row["deviation_deg"] == row["within_tolerance"] == "" and n < 3
        else:
            assert float(row["deviation_deg"]) == after and float(row["deviation_deg_before"]) == before
            assert row["within_tolerance"] == str(int(after <= 0.01))
    assert {row["within_tolerance"] for row in rows} == {"0", "1", ""}
    r = runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(TRUTH), "--per-pose",
                            str(tmp_path / "p.txt")])
    assert r.exit_code == 2 and "--per-pose" in r.stderr and ".csv" in r.stderr

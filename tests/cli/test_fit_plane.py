"""``metro fit-plane``: the table, --json, --out, --plot, determinism, every bad input."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import DATA_DIR
from metrology.core.plane import Plane

runner = CliRunner()


def test_cli_two_runs_identical_bytes(tmp_path):
    outs = []
    for k in range(2):
        out = tmp_path / f"p{k}.json"
        r = runner.invoke(app, ["fit-plane", str(DATA_DIR / "datum_cloud.ply"), "--out", str(out), "--seed", "3"])
        assert r.exit_code == 0, r.output
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


def test_cli_table_json_out_plot(tmp_path):
    out, png = tmp_path / "plane.json", tmp_path / "res.png"
    r = runner.invoke(app, ["fit-plane", str(DATA_DIR / "datum_cloud.ply")])
    assert r.exit_code == 0, r.output
    for key in ("normal (A, B, C)", "offset D", "inliers", "flatness (P-V)", "uncertainty (1 sd)", "form (quadratic)", "SIGNIFICANT"):
        assert key in r.stdout
    r = runner.invoke(app, ["fit-plane", str(DATA_DIR / "datum_cloud.ply"), "--json", "--out", str(out), "--plot", str(png)])
    assert r.exit_code == 0, r.output
    printed = json.loads(r.stdout)
    # --json is what --out holds, plus the verdict (no --flatness-mm: information only, passed)
    verdict = printed.pop("verdict")
    assert json.loads(out.read_text()) == printed and verdict["passed"] is True
    assert not any(c["gate"] for c in verdict["checks"])
    plane = Plane.from_json(out)
    np.testing.assert_array_equal(plane.normal, printed["normal"])
    assert plane.offset == printed["offset"] < 0
    assert printed["n_points"] == 3300 and printed["form"]["significant"] is True
    for key in ("normal_sigma_deg", "offset_sigma_mm", "rms_mm", "max_abs_residual_mm", "flatness_mm", "inlier_ratio", "covariance"):
        assert key in printed
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plane.json", "res.png"]


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def _cube(tmp_path):
    rng = np.random.default_rng(13)
    pts = rng.uniform(-100, 100, (2000, 3))
    return _write(tmp_path, "cube.xyz", "\n".join(" ".join(repr(float(v)) for v in p) for p in pts))


def _collinear(tmp_path):
    t = np.linspace(0, 100, 50)
    return _write(tmp_path, "line.csv", "x,y,z\n" + "\n".join(f"{v},{2 * v},{-v}" for v in t))


@pytest.mark.parametrize(
    "make, extra, match",
    [
        (lambda d: _write(d, "empty.ply", ""), [], r"empty\.ply: empty file"),
        (lambda d: _write(d, "two.csv", "1,2,3\n4,5,6\n"), [], r"two\.csv: 2 points, need at least 3"),
        (_collinear, [], r"line\.csv: points are collinear"),
        # NaN rows are missing returns: dropped with a count, refused only when too few remain
        (lambda d: _write(d, "nan.xyz", "1 2 3\nnan 1 1\nnan 5 6\n7 8 9\n"), [], r"nan\.xyz: 2 points of 4 \(2 with NaN dropped\), need at least 3"),
        (lambda d: _write(d, "abc.csv", "x,y,z\n1,2,3\n4,5,6\n7,8,z9\n"), [], r"abc\.csv: line 4, column 3: 'z9' is not a number"),
        (lambda d: _write(d, "cloud.stl", "solid\n"), [], r"cloud\.stl: unknown extension '\.stl' for CLOUD; expected one of \.csv"),
        (_cube, [], r"cube\.xyz: no datum plane: the cloud is .* thick"),
        (_cube, ["--threshold-mm", "0.05"], r"cube\.xyz: .*(no datum plane|all outliers)"),
        (lambda d: d / "missing.ply", [], r"missing\.ply: no such file"),
        (lambda d: _write(d, "ok.csv", "1,2,3\n4,5,7\n7,8,8\n1,9,1\n"), ["--threshold-mm", "-1"], r"threshold -1\.0 mm"),
    ],
)
def test_cli_bad_inputs(tmp_path, make, extra, match):
    cloud = make(tmp_path)
    out, png = tmp_path / "out" / "plane.json", tmp_path / "out" / "res.png"
    out.parent.mkdir()
    r = runner.invoke(app, ["fit-plane", str(cloud), *extra, "--out", str(out), "--plot", str(png)])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    import re

    assert re.search(match, lines[0]), lines[0]
    assert r.stdout == ""
    assert list(out.parent.iterdir()) == []  # nothing written, no temporary left


def test_cli_bad_output_paths_write_nothing(tmp_path):
    r = runner.invoke(app, ["fit-plane", str(DATA_DIR / "datum_cloud.ply"), "--out", str(tmp_path / "p.json"), "--plot", str(tmp_path / "r.bmp")])
    assert r.exit_code == 2 and "must be one of .pdf, .png, .svg" in r.stderr
    r = runner.invoke(app, ["fit-plane", str(DATA_DIR / "datum_cloud.ply"), "--plot", str(tmp_path / "r.png"), "--out", str(tmp_path / "no" / "p.json")])
    assert r.exit_code == 2 and "does not exist" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_metres_and_nan_rows_are_said_on_stderr_and_units_m_fits_in_mm(tmp_path):
    """A plate scanned in metres with missing returns: the NaN rows are dropped with a count,
    the size says metres (stderr, not the report), and --units m gives the plane in mm."""
    import numpy as np

    rng = np.random.default_rng(7)
    xy = rng.uniform([-0.2, -0.15], [0.2, 0.15], (3000, 2))
    pts = np.column_stack([xy, 0.5 + 0.01 * xy[:, 0] + rng.normal(0, 2e-5, len(xy))])  # metres
    pts[::10] = np.nan
    f = tmp_path / "scan.xyz"
    f.write_text("".join(f"{x:.7f} {y:.7f} {z:.7f}\n" for x, y, z in pts).replace("nan", "NaN"))
    r = runner.invoke(app, ["fit-plane", str(f), "--json"])
    assert "300 of 3000 points have NaN coordinates" in r.stderr and "looks like metres; pass --units m" in r.stderr
    r = runner.invoke(app, ["fit-plane", str(f), "--json", "--units", "m"])
    assert r.exit_code == 0, r.output
    assert "looks like metres" not in r.stderr and "300 of 3000" in r.stderr
    d = json.loads(r.stdout)
    assert d["read"]["n_dropped_nonfinite"] == 300 and d["read"]["units"] == "m"
    assert d["n_points"] == 2700 and abs(d["noise_sigma_mm"] - 0.02) < 0.005  # 20 um, in mm

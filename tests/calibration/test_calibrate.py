"""metro calibrate / validate on fixtures/measured: truth recovery, identifiability, bad input."""

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from tests.calibration.helpers import export_rows, write_rows
from metrology.io.data import DATA_DIR
from metrology.calibration.calibrate import DEFAULT_METHOD, calibrate_dataset
from metrology.calibration.identifiability import describe_combination, identifiability
from metrology.calibration.validation import validate
from metrology.calibration.dataset import load_dataset
from metrology.core.observations import Observations
from metrology.io.layout import load_layout
from metrology.core.model import direction_basis, tangent_from_direction
from metrology.core.tolerances import CORRELATION_REPORT, RANK_RTOL

FIX = DATA_DIR / "measured"
CAL, VAL = FIX / "calibration.csv", FIX / "validation.csv"
PLANE, NOMINAL, TRUTH = FIX / "plane.json", FIX / "nominal.toml", FIX / "truth.toml"
runner = CliRunner()


@pytest.fixture(scope="module")
def report():
    return calibrate_dataset(load_dataset(CAL, PLANE, NOMINAL))


def _truth_theta(nominal):
    truth = load_layout(TRUTH)
    return np.concatenate([truth.zero - nominal.zero, tangent_from_direction(nominal.direction, truth.direction)], axis=1)


# ---------------------------------------------------------------------------------------
# accuracy against the truth that generated the fixture


def test_default_method_recovers_truth_within_reported_uncertainty(report):
    cal = report.calibration
    assert cal.method == DEFAULT_METHOD
    z = (cal.theta - _truth_theta(cal.nominal)) / cal.stderr
    # 20 parameters: all within 4 sigma, and the spread of z is that of a standard normal
    assert np.all(np.abs(z) < 4.0), np.round(z, 2)
    assert 0.3 < np.sqrt(np.mean(z**2)) < 2.0
    # the zero point along the tool axis is determined to a few um; the pivot is not
    assert np.all(cal.stderr[:, 2] < 0.02)
    assert np.all(cal.stderr[:, :2] > 3 * cal.stderr[:, 2:3])


def test_iekf_agrees_with_lsq_and_paper_ekf_does_not(report):
    ds = report.dataset
    cal = report.calibration
    it = calibrate_dataset(ds, "iekf").calibration
    assert np.all(np.abs(it.theta - cal.theta) < 0.1 * cal.stderr)
    paper = calibrate_dataset(ds, "ekf_paper").calibration
    err_paper = np.abs(paper.theta - _truth_theta(cal.nominal))
    err_lsq = np.abs(cal.theta - _truth_theta(cal.nominal))
    assert err_paper.max() > 3 * err_lsq.max()
    assert paper.n_converged.shape == (4,)


def test_validate_improves_on_nominal_and_reaches_truth(report):
    vds = load_dataset(VAL, PLANE, NOMINAL)
    v = validate(vds, {"nominal": vds.layout, "calibrated": report.layout, "truth": load_layout(TRUTH)})
    before, after, truth = (v.stats_deg(k) for k in range(3))
    assert after["mean_deg"] < 0.1 * before["mean_deg"]
    assert after["max_deg"] < 0.05
    # the calibrated layout validates within 20 % + 1 mdeg of the true one
    assert after["mean_deg"] < 1.2 * truth["mean_deg"] + 1e-3
    assert before["n_poses"] == after["n_poses"] >= 15


# ---------------------------------------------------------------------------------------
# identifiability


def test_gauge_and_pivot_are_named(report):
    for ident in report.identifiability:
        assert ident.raw_gauge_cos > 0.99
        assert "gauge" in ident.raw_null_words
        assert ident.raw_singular[-1] < RANK_RTOL
        assert "pivot" in ident.words[-1]
        # the pivot hardly moves the measured normal
        assert np.rad2deg(ident.normal_effect[-1]) < 0.01
    # the pivot point is at the mean spot: compute it independently
    ident = report.identifiability[0]
    _, t = describe_combination(ident.chart_vectors[-1], report.layout.direction[0],
                                direction_basis(report.calibration.nominal.direction)[0], 50.0)
    mean_reading = np.nanmean(report.dataset.obs.d[:, 0])
    assert abs(t - mean_reading) < 3.0


def test_identifiability_gives_a_computed_fix(report):
    ident = report.identifiability[0]
    assert ident.warnings, "5 deg tilts leave the lateral zero above the 0.05 mm target"
    fix = ident.fix
    assert fix["poses_needed_at_current_spread"] > fix["n_poses"]
    found = fix["within_range"] or fix["ignoring_range"]
    assert found is not None and found["tilt_max_deg"] > ident.tilt_max_deg
    assert np.all(np.asarray(found["predicted_stderr"]["zero_mm"]) <= 0.05)


def test_identifiability_flags_a_pose_set_without_tilt(report):
    nominal = report.calibration.nominal
    layout = report.layout
    obs = report.dataset.obs
    normal = np.repeat(obs.normal.mean(axis=0, keepdims=True), 30, axis=0)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offset = np.linspace(obs.offset.min(), obs.offset.max(), 30)
    from metrology.core.model import readings

    flat = Observations(normal, offset, readings(layout.zero, layout.direction, normal, offset)[0])
    idents = identifiability(nominal, layout, report.calibration.theta, flat, np.full(4, 0.003))
    for ident in idents:
        # no tilt: only the inclination to the datum and the height along it are seen
        assert np.sum(ident.chart_singular <= RANK_RTOL) == 3
        assert any("not determined" in w for w in ident.warnings)
        assert ident.tilt_max_deg < 1e-6
        assert ident.fix["within_range"] is not None or ident.fix["ignoring_range"] is not None


# ---------------------------------------------------------------------------------------
# the command line


def test_calibrate_text_advises_and_warns_on_stderr_only():
    """The report says what to do (the precision against the target and how to reach it; the
    residuals above the stated noise point to diagnose) and prints no warning on stdout."""
    r = runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL)])
    assert r.exit_code == 0, r.output
    assert "warning" not in r.stdout
    assert "precision: 1 sigma up to" in r.stdout and "to reach it: poses tilted up to" in r.stdout
    # the fixture carries tracker pose noise: 6-8 um residuals against 3 um stated
    assert "metro diagnose" in r.stdout
    # a target the poses already meet: no precision advice
    r = runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL),
                            "--target-mm", "1", "--target-deg", "1"])
    assert r.exit_code == 0 and "precision:" not in r.stdout


def test_calibrate_cli_json_and_outputs(tmp_path):
    out = tmp_path / "calibrated.toml"
    r = runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL), "--json",
                            "--out", str(out)])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert d["method"] == DEFAULT_METHOD
    assert [s["name"] for s in d["sensors"]] == ["L1", "L2", "L3", "L4"]
    s = d["sensors"][0]
    for key in ("nominal", "error", "corrected", "residual_rms_mm", "correlations", "n_converged", "n_readings"):
        assert key in s
    assert set(s["error"]) >= {"zero_mm", "zero_stderr_mm", "tilt_deg", "tilt_stderr_deg"}
    assert all(abs(c["r"]) > CORRELATION_REPORT for c in s["correlations"])
    ident = d["identifiability"][0]
    assert len(ident["chart"]["relative_singular_values"]) == 5 and len(ident["raw"]["relative_singular_values"]) == 6
    assert d["warnings"]
    # the written layout reads back, with standard errors, and is the reported one
    cal = load_layout(out)
    assert cal.names == ("L1", "L2", "L3", "L4") and cal.zero_stderr_mm is not None
    assert np.allclose(cal.zero[0], s["corrected"]["zero_mm"], atol=1e-6)


def test_calibrate_cli_paper_ekf_reports_convergence(tmp_path):
    r = runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL), "--json",
                            "--method", "ekf_paper", "--plot", str(tmp_path / "figs")])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    assert all(s["n_converged"] is None or s["n_converged"] > 0 for s in d["sensors"])
    assert (tmp_path / "figs" / "convergence.png").stat().st_size > 10_000
    assert (tmp_path / "figs" / "residuals.png").stat().st_size > 10_000


def test_validate_cli_json(tmp_path):
    cal = tmp_path / "cal.toml"
    assert runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL),
                               "--out", str(cal)]).exit_code == 0
    png = tmp_path / "fig12.png"
    r = runner.invoke(app, ["validate", str(VAL), "--plane", str(PLANE), "--layout", str(cal),
                            "--layout-before", str(NOMINAL), "--json", "--plot", str(png)])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    for label in ("layout_before", "layout"):
        assert set(d["layouts"][label]) >= {"max_deg", "mean_deg", "std_deg", "deviation_deg", "n_poses"}
        assert len(d["layouts"][label]["deviation_deg"]) == d["n_poses"] == 20
    assert d["layouts"]["layout"]["mean_deg"] < 0.1 * d["layouts"]["layout_before"]["mean_deg"]
    assert png.stat().st_size > 10_000




def _drop_column(rows, name):
    k = rows[0].index(name)
    return [r[:k] + r[k + 1:] for r in rows]


def _set(rows, line, column, value):
    rows = [list(r) for r in rows]
    rows[line - 1][rows[0].index(column)] = value
    return rows


def _bad_export(case, tmp_path):
    rows = export_rows()
    if case == "missing column":
        return write_rows(tmp_path / "x.csv", _drop_column(rows, "qz")), NOMINAL, "missing column"
    if case == "sensor not in layout":
        rows = [r + ([("d_L5")] if i == 0 else ["50.0"]) for i, r in enumerate(rows)]
        return write_rows(tmp_path / "x.csv", rows), NOMINAL, "L5 not in the layout"
    if case == "layout sensor not in export":
        return write_rows(tmp_path / "x.csv", _drop_column(rows, "d_L4")), NOMINAL, "no reading column .*L4"
    if case == "layout lacks a sensor":
        text = NOMINAL.read_text()
        cut = text.index('[[sensors]]\nname = "L4"')
        three = tmp_path / "three.toml"
        three.write_text(text[:cut])
        return CAL, three, "L4 not in the layout"
    if case == "non-unit quaternion":
        qw = float(rows[3][rows[0].index("qw")])
        return write_rows(tmp_path / "x.csv", _set(rows, 4, "qw", f"{qw + 0.05:.12f}")), NOMINAL, "line 4: quaternion norm"
    if case == "reading out of range":
        return write_rows(tmp_path / "x.csv", _set(rows, 6, "d_L2", "75.0")), NOMINAL, r"d_L2 = 75 mm outside"
    if case == "too few poses":
        return write_rows(tmp_path / "x.csv", rows[:5]), NOMINAL, "has [0-9] readings, need at least 6"
    if case == "NaN":
        return write_rows(tmp_path / "x.csv", _set(rows, 7, "d_L3", "nan")), NOMINAL, "line 7: column 'd_L3' = 'nan'"
    if case == "not a number":
        return write_rows(tmp_path / "x.csv", _set(rows, 9, "x", "12,5")), NOMINAL, "line 9"
    raise AssertionError(case)


BAD = ["missing column", "sensor not in layout", "layout sensor not in export", "layout lacks a sensor",
       "non-unit quaternion", "reading out of range", "too few poses", "NaN", "not a number"]


@pytest.mark.parametrize("case", BAD)
@pytest.mark.parametrize("command", ["calibrate", "validate"])
def test_bad_input_one_line_exit_2_nothing_written(case, command, tmp_path):
    import re

    export, layout, pattern = _bad_export(case, tmp_path)
    out, figs, png = tmp_path / "cal.toml", tmp_path / "figs", tmp_path / "v.png"
    extra = ["--out", str(out), "--plot", str(figs)] if command == "calibrate" else ["--plot", str(png)]
    before = sorted(p.name for p in tmp_path.iterdir())
    r = runner.invoke(app, [command, str(export), "--plane", str(PLANE), "--layout", str(layout), *extra])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert re.search(pattern, lines[0]), lines[0]
    assert "Traceback" not in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_missing_output_directory_fails_before_work(tmp_path):
    out = tmp_path / "nowhere" / "cal.toml"
    r = runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL), "--out", str(out)])
    assert r.exit_code == 2
    assert r.stderr.startswith("error: --out") and not out.parent.exists()


def test_unknown_method_is_one_line_error():
    r = runner.invoke(app, ["calibrate", str(CAL), "--plane", str(PLANE), "--layout", str(NOMINAL), "--method", "magic"])
    assert r.exit_code == 2 and r.stderr.count("\n") == 1 and "magic" in r.stderr


# ---------------------------------------------------------------------------------------
# the fixture itself


def test_fixture_regenerates_byte_for_byte(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_measured", Path(__file__).resolve().parents[2] / "fixtures" / "make_measured.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.main(tmp_path)
    for f in sorted(FIX.iterdir()):
        assert (tmp_path / f.name).read_bytes() == f.read_bytes(), f.name
    assert sum(f.stat().st_size for f in FIX.iterdir()) < 1_000_000


def test_fixture_plane_json_matches_the_datum_cloud():
    from metrology.io.clouds import read_cloud
    from metrology.calibration.dataset import load_plane
    from metrology.core.normals import angle_between
    from metrology.core.plane import Plane, fit_plane_tls

    pts = read_cloud(FIX / "datum.ply")
    assert 2000 <= len(pts) <= 3000
    plane = Plane.from_json(PLANE)
    r = plane.distance(pts)
    inliers = np.abs(r) < 5 * 0.015
    assert 0.95 < inliers.mean() < 0.99  # a few % outliers
    tls, _, rms = fit_plane_tls(pts[inliers])
    # arctan2 of |cross| and |dot|: no arccos of a dot product that rounds above 1
    assert np.degrees(angle_between(tls.normal, plane.normal)) < 1e-3
    # --plane accepts the cloud itself: the robust fit agrees with the JSON
    fitted, inlier_pts = load_plane(FIX / "datum.ply")
    assert np.degrees(np.arccos(abs(fitted.normal @ plane.normal))) < 2e-3
    assert abs(fitted.offset - plane.offset) < 0.01
    assert 0.95 < len(inlier_pts) / len(pts) < 0.99


@pytest.mark.parametrize("history", [False, True])
def test_convergence_legends_sit_clear_of_title_and_data(report, history):
    """Issue 51, item 12: the convergence figure's legends overlapped the title and the curves; each now sits in a
    row of its own, clear of the title and of every axes' data area (a batch method's bands, a filter's history)."""
    import dataclasses

    from metrology.report.calibration import convergence_figure

    rep = report
    if history:  # a filter's estimate after each measurement
        m = len(report.dataset.obs.d)
        hist = [np.zeros((m, 6)) + i * 1e-3 for i in range(len(report.layout.names))]
        rep = dataclasses.replace(report, calibration=dataclasses.replace(report.calibration, history=hist))
    fig = convergence_figure(rep)
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    title = fig._suptitle.get_window_extent(r)
    legends = [ax.get_legend().get_window_extent(r) for ax in fig.axes if ax.get_legend() is not None]
    assert len(legends) == 2
    for leg in legends:
        assert not leg.overlaps(title)
        for ax in fig.axes:
            assert not leg.overlaps(ax.get_window_extent(r)), ax.get_ylabel()
        assert 0 <= leg.x0 and leg.x1 <= fig.bbox.x1 and leg.y1 <= fig.bbox.y1
    import matplotlib.pyplot as plt

    plt.close(fig)

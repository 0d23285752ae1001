"""Plausible mistakes in a user's tracker export (issue 11, section 4): never a silent calibration.

Each mistaken export is made from the bundled measured fixture by rewriting its text the way the
mistake would (columns reordered, positions rescaled, headers swapped, codes typed in); the
commands must exit 2 with one line naming the mistake and write nothing, and the option that
accepts the mistake must give back the calibration of the correct file.
"""

import json
import re

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from tests.calibration.helpers import export_rows, write_rows
from metrology.calibration.dataset import drop_no_reading, load_dataset
from metrology.calibration.sanity import GROSS_NOISE_FACTOR, GROSS_P, explain, screen
from metrology.io.data import DATA_DIR
from metrology.io.export import read_export
from metrology.io.layout import load_layout

FIX = DATA_DIR / "measured"
CAL, PLANE, NOMINAL = FIX / "calibration.csv", FIX / "plane.json", FIX / "nominal.toml"
runner = CliRunner()




def _map_columns(rows, columns, fn):
    """Rewrite the cells of ``columns`` in every pose row with ``fn(list of str) -> list of str``."""
    k = [rows[0].index(c) for c in columns]
    out = [list(rows[0])]
    for r in rows[1:]:
        r = list(r)
        for j, v in zip(k, fn([r[j] for j in k])):
            r[j] = v
        out.append(r)
    return out


def _scalar_last(rows):
    # an exporter that writes (x, y, z, w) under the header qw,qx,qy,qz
    return _map_columns(rows, ["qw", "qx", "qy", "qz"], lambda q: [q[1], q[2], q[3], q[0]])


def _positions(rows, mm_per_unit):
    return _map_columns(rows, ["x", "y", "z"], lambda p: [f"{float(v) / mm_per_unit:.15g}" for v in p])


def _swap_headers(rows, a, b):
    head = list(rows[0])
    i, j = head.index(a), head.index(b)
    head[i], head[j] = head[j], head[i]
    return [head] + rows[1:]


def _readings(rows, factor):
    cols = [c for c in rows[0] if c.startswith("d_")]
    return _map_columns(rows, cols, lambda d: [f"{float(v) * factor:.15g}" if v else "" for v in d])


def _set_cells(rows, cells, value):
    rows = [list(r) for r in rows]
    for line, col in cells:
        rows[line - 1][rows[0].index(col)] = value
    return rows


def _no_range_layout(tmp_path):
    text = "\n".join(ln for ln in NOMINAL.read_text().splitlines() if not ln.startswith("range_mm"))
    path = tmp_path / "norange.toml"
    path.write_text(text + "\n")
    return path


MISTAKES = {
    "scalar-last quaternions": (_scalar_last, "quaternions look scalar-last \\(x, y, z, w\\)",
                                "--quaternion-order xyzw"),
    "positions in metres": (lambda r: _positions(r, 1000.0), "positions look like metres", "--position-units m"),
    "positions in inches": (lambda r: _positions(r, 25.4), "positions look like inches", "--position-units in"),
    "two sensor columns swapped": (lambda r: _swap_headers(r, "d_L2", "d_L4"),
                                   "columns d_L2 and d_L4 look swapped", "swap the two column headers"),
    "readings in microns": (lambda r: _readings(r, 1000.0), "readings look like microns", "in mm"),
    "readings in metres": (lambda r: _readings(r, 1e-3), "readings look like metres", "in mm"),
}


def _invoke(command, export, layout, tmp_path, *extra):
    outs = {"calibrate": ["--out", str(tmp_path / "cal.toml"), "--plot", str(tmp_path / "figs")],
            "validate": ["--plot", str(tmp_path / "v.png")],
            "diagnose": ["--report", str(tmp_path / "rep")]}[command]
    return runner.invoke(app, [command, str(export), "--plane", str(PLANE), "--layout", str(layout), *outs, *extra])


def _mistake_cases():
    """Every mistake for calibrate and for diagnose (two screens: diagnose lets a few gross readings
    through); validate reads through calibrate's screen (``load_checked`` as calibrate does), so one
    mistake checks its exit and that it writes nothing, the other five run with the slow tests (issue 51
    item 15: the default run's time). Diagnose's swapped columns too: a swap is a mistake, not a few
    gross readings, so diagnose's screen searches the same hypotheses as calibrate's (the default
    ``calibrate-two sensor columns swapped``) and refuses as for its five other mistakes."""
    def slow(c, i, m):
        return (c == "validate" and i) or (c == "diagnose" and m == "two sensor columns swapped")

    return [pytest.param(m, c, id=f"{c}-{m}", marks=[pytest.mark.slow] if slow(c, i, m) else [])
            for c in ("calibrate", "validate", "diagnose") for i, m in enumerate(MISTAKES)]


@pytest.mark.parametrize("mistake, command", _mistake_cases())
def test_mistake_is_named_exit_2_nothing_written(mistake, command, tmp_path):
    make, words, fix = MISTAKES[mistake]
    export = write_rows(tmp_path / "export.csv", make(export_rows()))
    before = sorted(p.name for p in tmp_path.iterdir())
    r = _invoke(command, export, NOMINAL, tmp_path)
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert re.search(words, lines[0]) and fix in lines[0], lines[0]
    assert "Traceback" not in r.output and r.stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.parametrize("mistake", ["scalar-last quaternions", "readings in microns",
                                     pytest.param("two sensor columns swapped", marks=pytest.mark.slow)])
def test_mistake_is_named_without_a_stated_range(mistake, tmp_path):
    """Without range_mm the reading units are caught by the fit, not the range check. (The swap is
    slow: the four sensors share one range, so no range check sees it; with the range stated it is
    the default ``test_mistake_is_named_exit_2_nothing_written[calibrate-two sensor columns swapped]``.)"""
    make, words, fix = MISTAKES[mistake]
    export = write_rows(tmp_path / "export.csv", make(export_rows()))
    r = _invoke("calibrate", export, _no_range_layout(tmp_path), tmp_path)
    assert r.exit_code == 2 and re.search(words, r.stderr) and fix in r.stderr, r.stderr
    assert not (tmp_path / "cal.toml").exists()


def _calibrate_json(export, tmp_path, *extra):
    r = runner.invoke(app, ["calibrate", str(export), "--plane", str(PLANE), "--layout", str(NOMINAL), "--json",
                            *extra])
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout)
    return d, np.array([[*s["error"]["zero_mm"], *s["error"]["tilt_deg"]] for s in d["sensors"]]), r.stderr


@pytest.fixture(scope="module")
def correct(tmp_path_factory):
    return _calibrate_json(CAL, tmp_path_factory.mktemp("correct"))


@pytest.mark.parametrize("mistake, option", [("scalar-last quaternions", ["--quaternion-order", "xyzw"]),
                                             ("positions in metres", ["--position-units", "m"]),
                                             ("positions in inches", ["--position-units", "in"])])
def test_the_named_option_reads_the_mistaken_file_as_the_correct_one(mistake, option, correct, tmp_path):
    export = write_rows(tmp_path / "export.csv", MISTAKES[mistake][0](export_rows()))
    _, theta, _ = _calibrate_json(export, tmp_path, *option)
    # the same data up to the 15 significant digits the rescaled file was written with
    np.testing.assert_allclose(theta, correct[1], rtol=0, atol=1e-6)


def test_a_correct_file_passes_the_screen():
    ds = load_dataset(CAL, PLANE, NOMINAL)
    s = screen(ds)
    assert not s.gross and explain(ds) is None
    # the fixture's residuals are above the stated noise (pose noise the model does not know)
    # but far from the gross rule
    assert np.all(s.residual_rms > ds.layout.noise_mm) and np.all(s.residual_rms < GROSS_NOISE_FACTOR * s.noise_mm)
    assert np.all(s.zero_shift_mm < 2.0) and np.all(s.tilt_deg < 3.0)


def test_the_gross_rule_is_the_stated_chi_square_rule(tmp_path):
    """Scalar-last quaternions: residuals thousands of times the noise, p far below GROSS_P."""
    ds = load_dataset(write_rows(tmp_path / "x.csv", _scalar_last(export_rows())), PLANE, NOMINAL)
    s = screen(ds)
    assert s.gross and np.all(s.noise_fails)
    assert np.all(s.residual_rms > 1000 * s.noise_mm) and np.all(s.p_value < GROSS_P)
    m = explain(ds)
    assert m.mistake.startswith("quaternions look scalar-last") and m.fitted.score < 0.02


# ---------------------------------------------------------------------------------------
# "no reading" codes


ZERO_CELLS = [(3, "d_L1"), (10, "d_L3"), (11, "d_L3"), (40, "d_L4")]


def test_zero_readings_are_dropped_with_a_count_never_used(correct, tmp_path):
    rows = export_rows()
    assert all(rows[line - 1][rows[0].index(c)] for line, c in ZERO_CELLS)  # real readings there
    zeros = write_rows(tmp_path / "zeros.csv", _set_cells(rows, ZERO_CELLS, "0"))
    blanks = write_rows(tmp_path / "blanks.csv", _set_cells(rows, ZERO_CELLS, ""))
    d0, theta0, err0 = _calibrate_json(zeros, tmp_path)
    db, thetab, errb = _calibrate_json(blanks, tmp_path)
    np.testing.assert_array_equal(theta0, thetab)  # a 0 is exactly a blank: no reading
    assert [s["n_readings"] for s in d0["sensors"]] == [s["n_readings"] for s in db["sensors"]]
    assert [a["n_readings"] - b["n_readings"] for a, b in zip(correct[0]["sensors"], d0["sensors"])] == [1, 0, 2, 1]
    assert d0["no_reading"]["value"] == 0 and d0["no_reading"]["dropped"] == 4
    assert {(x["pose_id"], x["sensor"]) for x in d0["no_reading"]["readings"]} == \
        {(rows[line - 1][0], c[2:]) for line, c in ZERO_CELLS}
    assert "no_reading" not in db and "no_reading" not in correct[0]
    assert re.search(r"warning: .*zeros.csv: 4 reading\(s\) equal to the no-reading code 0 dropped in 4 pose\(s\)",
                     err0), err0


@pytest.mark.parametrize("command", ["calibrate", "validate"])
def test_an_unknown_code_is_refused_naming_the_pose_then_accepted_with_no_reading(command, tmp_path):
    # the first 16 poses (lines 3, 10, 11 among them): the refusal and the run with the code are what is
    # checked, and calibrate's --plot on the 100 poses drew its convergence figure from 97 fits
    export = write_rows(tmp_path / "x.csv", _set_cells(export_rows()[:17], ZERO_CELLS[:3], "-999"))
    r = _invoke(command, export, NOMINAL, tmp_path)
    assert r.exit_code == 2
    assert re.search(r"pose C002: d_L1 = -999 mm outside the sensor's range \[40, 60\] mm .*"
                     r"3 of them read exactly -999: .*pass --no-reading -999", r.stderr), r.stderr
    r = _invoke(command, export, NOMINAL, tmp_path, "--no-reading", "-999", "--json")
    # it runs: validate's verdict on the nominal layout is out of the 0.5 deg tolerance (exit 1)
    assert r.exit_code == {"calibrate": 0, "validate": 1}[command], r.output
    assert json.loads(r.stdout)["no_reading"]["dropped"] == 3 and "-999 dropped" in r.stderr


def test_an_unknown_code_without_a_range_is_refused_by_the_fit(tmp_path):
    export = write_rows(tmp_path / "x.csv", _set_cells(export_rows()[:41], ZERO_CELLS, "9999"))  # 40 poses: line 40 in
    r = _invoke("calibrate", export, _no_range_layout(tmp_path), tmp_path)
    assert r.exit_code == 2
    assert re.search(r"do not fit the poses and the datum: .* furthest from the fit is pose C0[0-9]+ "
                     r"d_L[1-4] = 9999 mm.* pass --no-reading 9999", r.stderr), r.stderr
    assert not (tmp_path / "cal.toml").exists()


def test_zero_is_a_distance_for_a_sensor_whose_range_contains_it():
    layout = load_layout(NOMINAL)
    export = read_export(CAL).reordered(layout.names)
    d = export.d.copy()
    d[2, 0] = 0.0
    from dataclasses import replace

    export = replace(export, d=d)
    _, dropped = drop_no_reading(export, layout)
    assert dropped == ((export.pose_id[2], "L1"),)
    wide = replace(layout, range_mm=np.tile([-10.0, 60.0], (layout.n, 1)))
    kept, dropped = drop_no_reading(export, wide)
    assert dropped == () and kept.d[2, 0] == 0.0
    # an explicit code applies whatever the range
    _, dropped = drop_no_reading(export, wide, 0.0)
    assert dropped == ((export.pose_id[2], "L1"),)


def test_a_few_gross_readings_pass_the_screen_a_swapped_column_does_not(tmp_path):
    # a blind case of the independent simulator (the study's seed-60 first pair): a drift and six
    # gross readings of 0.3-1.9 mm on a 3-sensor head. Plain least squares follows the gross
    # readings 11.9 mm and 11.9 deg along a direction the poses leave weak, and the screen
    # refused the run as an export mistake; the robust refit stays within 1.0 mm and 1.3 deg.
    # The same run with two sensor columns swapped is still refused.
    from metrology.calibration.estimators import lsq
    from metrology.calibration.sanity import GROSS_ZERO_MM, check_dataset
    from metrology.sim.forward import draw_pair, write_case

    case = draw_pair(np.random.default_rng([60, 3, 0, 0]), "drift", "outliers")
    assert [e.family for e in case.effects] == ["drift", "outliers"] and case.nominal.n == 3
    paths = write_case(case, tmp_path)
    ds = load_dataset(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])
    plain = lsq(ds.layout, ds.obs)
    assert np.max(np.linalg.norm(plain.layout.zero - ds.layout.zero, axis=1)) > GROSS_ZERO_MM
    s = screen(ds)
    assert not s.gross and np.all(s.zero_shift_mm < 2.0) and np.all(s.tilt_deg < 3.0)
    check_dataset(ds, str(paths["export.csv"]), "wxyz", "mm")  # no error
    swapped = write_rows(tmp_path / "swapped.csv", _swap_headers(export_rows(paths["export.csv"]), "d_L1", "d_L3"))
    bad = load_dataset(swapped, paths["cloud.ply"], paths["layout.toml"])
    assert screen(bad).gross
    m = explain(bad)
    assert m is not None and m.mistake is not None and "swapped" in m.mistake


def test_gross_readings_far_above_the_noise_are_named_for_calibrate_and_let_through_for_diagnose(tmp_path):
    # a blind case of the independent simulator (the seed-70 study's outliers draw 8): three
    # gross readings of 1.2-2.0 mm on L2 and one on L3, 59 poses, 3 um noise. L2's residual RMS
    # is 0.33 mm, 109 times the noise (the noise test of an export mistake), and `diagnose`
    # refused the run as one; the robust refit's scale on L2 is 3.7 um. A calibration is still
    # refused (it would follow them), now saying what they are; `diagnose` gets the data. The
    # same run with two sensor columns swapped is refused for both.
    from metrology.calibration.sanity import check_dataset
    from metrology.sim.forward import draw_case, write_case

    case = draw_case(np.random.default_rng([70, 1, 6, 8]), "outliers")
    cells = case.effects[0].shape["cells"]
    assert case.effects[0].sensors == ("L2", "L3") and max(abs(c[2]) for c in cells) > 1.9
    paths = write_case(case, tmp_path)
    ds = load_dataset(paths["export.csv"], paths["cloud.ply"], paths["layout.toml"])
    s = screen(ds)
    i = list(ds.layout.names).index("L2")
    assert s.gross and not s.mistaken and s.gross_readings[i]
    assert s.residual_rms[i] > GROSS_NOISE_FACTOR * s.noise_mm[i] and s.robust_scale_mm[i] < 2 * s.noise_mm[i]
    with pytest.raises(ValueError, match=r"export.csv: a few gross readings: the residual RMS of L2 is 0.33 mm .*"
                                         r"robust fit leaves 0.00[0-9]+ mm with 3 of its 59 readings far from it; "
                                         r".* pose P004 d_L2 = .*metro diagnose"):
        check_dataset(ds, str(paths["export.csv"]))
    check_dataset(ds, str(paths["export.csv"]), allow_gross_readings=True)  # no error
    swapped = write_rows(tmp_path / "swapped.csv", _swap_headers(export_rows(paths["export.csv"]), "d_L1", "d_L3"))
    bad = load_dataset(swapped, paths["cloud.ply"], paths["layout.toml"])
    assert screen(bad).mistaken
    with pytest.raises(ValueError, match="swapped"):
        check_dataset(bad, str(swapped), allow_gross_readings=True)


@pytest.mark.parametrize("mistake", ["swap a fifth of the rows", "shift 40 % of a column", "shift from a pose on"])
def test_a_mistake_in_part_of_the_export_is_no_few_gross_readings(mistake):
    # a mistake can misplace a block of readings, not all of them: the robust refit then still
    # fits the rest (its scale near the noise for a fifth of the rows swapped), but too many
    # readings are far from it to be a few gross readings; refused for diagnose too
    from dataclasses import replace

    from metrology.calibration.sanity import check_dataset

    ds = load_dataset(CAL, PLANE, NOMINAL)
    d = ds.export.d.copy()
    p = len(d)
    if mistake == "swap a fifth of the rows":
        rows = np.arange(0, p, 5)
        d[rows, 0], d[rows, 2] = ds.export.d[rows, 2], ds.export.d[rows, 0]
    elif mistake == "shift 40 % of a column":
        d[: int(0.4 * p), 0] += 2.0
    else:
        d[p // 2:, 0] += 5.0
    bad = replace(ds, export=replace(ds.export, d=d))
    s = screen(bad)
    assert s.gross and s.mistaken and not s.gross_readings.any()
    with pytest.raises(ValueError, match=r"^CAL.csv: (?!a few gross readings)"):
        check_dataset(bad, "CAL.csv", allow_gross_readings=True)

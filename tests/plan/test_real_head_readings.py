"""Issue 32: a planned pose read just past its range on the real head (not the nominal one) is
dropped as a blank with a warning naming it; more than a handful, far past the range, or a
repeated value (a code) are still refused (metrology.calibration.dataset.drop_out_of_range)."""

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.calibration.dataset import MAX_OUT_OF_RANGE_SHARE, drop_out_of_range
from metrology.io.data import DATA_DIR
from metrology.io.export import read_export
from metrology.io.layout import load_layout

M = DATA_DIR / "measured"


def _export_with(tmp_path, cells):
    """The bundled measured export with ``cells`` {(row, column): text} replaced."""
    rows = list(csv.reader(open(M / "calibration.csv", newline="")))
    for (r, col), text in cells.items():
        rows[r][rows[0].index(col)] = text
    path = tmp_path / "x.csv"
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return path


def _load(path):
    layout = load_layout(M / "nominal.toml")
    return read_export(path).reordered(layout.names), layout


def test_a_few_readings_just_past_the_range_become_blanks_named_in_a_warning(tmp_path):
    path = _export_with(tmp_path, {(3, "d_L2"): "39.41", (10, "d_L4"): "60.8"})  # range [40, 60]
    export, layout = _load(path)
    said = []
    out = drop_out_of_range(export, layout, "x.csv", said.append)
    assert np.isnan(out.d[2, 1]) and np.isnan(out.d[9, 3])
    assert np.array_equal(np.isnan(out.d), np.isnan(export.d) | np.isin(np.arange(out.d.size), [2 * 4 + 1, 9 * 4 + 3]).reshape(out.d.shape))
    assert len(said) == 1
    assert "2 of" in said[0] and "pose C003 d_L2 = 39.41 mm" in said[0] and "pose C010 d_L4 = 60.8 mm" in said[0]


@pytest.mark.parametrize("case", ["too_many", "far_past", "repeated_code"])
def test_otherwise_the_readings_are_left_for_the_range_check_to_refuse(tmp_path, case):
    export, layout = _load(M / "calibration.csv")
    allowed = int(MAX_OUT_OF_RANGE_SHARE * np.isfinite(export.d).sum())
    if case == "too_many":
        cells = {(1 + k, "d_L3"): f"{39.5 - 0.01 * k:.2f}" for k in range(allowed + 1)}
    elif case == "far_past":  # 15 mm past a 20 mm range
        cells = {(3, "d_L2"): "75"}
    else:
        cells = {(3, "d_L2"): "61", (4, "d_L2"): "61"}
    export, layout = _load(_export_with(tmp_path, cells))
    said = []
    assert drop_out_of_range(export, layout, "x.csv", said.append) is export and said == []


def test_calibrate_runs_on_a_reading_just_past_the_range_and_says_so(tmp_path):
    path = _export_with(tmp_path, {(3, "d_L2"): "39.41"})
    r = CliRunner().invoke(app, ["calibrate", str(path), "--plane", str(M / "datum.ply"), "--layout",
                                 str(M / "nominal.toml"), "--json"])
    assert r.exit_code == 0, r.output
    assert "warning: " in r.stderr and "pose C003 d_L2 = 39.41 mm" in r.stderr and "dropped as blanks" in r.stderr

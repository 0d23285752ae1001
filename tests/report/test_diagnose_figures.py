"""The figures, tables and text of ``metro diagnose``'s report: the overview grid only where the
base residuals carry structure, held-out residuals before and after the cause named, the text
tables' numbers under their headers, one spelling of micrometres."""

from __future__ import annotations

import re

import numpy as np
import pytest

from metrology.diagnosis.stats import Trend
from metrology.io.data import DATA_DIR
from metrology.report.diagnose import (GRID_MAX_VARIABLES, _grid, diagnosis_figures, discrepancy_lines, report_text,
                                       structure_rows, structured_cells)

_NUM = re.compile(r"-?\d+\.\d+")


@pytest.fixture(scope="module")
def measured():
    """The README's bundled run (fixtures/make_measured.py, the forward model): a rigid pose
    error named; its in-sample residuals fall below the stated noise, its held-out ones do not."""
    from metrology.jobs.diagnose import diagnose_files

    m = DATA_DIR / "measured"
    return diagnose_files(m / "calibration.csv", m / "plane.json", m / "nominal.toml")


@pytest.fixture(scope="module")
def drift(hidden_diagnosis):
    """The demo's hidden run: a temperature drift on L3 (diagnosed once a run, tests/conftest.py)."""
    return hidden_diagnosis


def _ends(line, pattern):
    return [m.end() for m in pattern.finditer(line)]


def _check_aligned(lines, n_sensors):
    """Each number of the discrepancy table ends where its column's header ends."""
    head = _ends(lines[1], re.compile(r"\S+"))
    assert len(head) == n_sensors + 1  # the sensors and "normal"
    for line in lines[2:]:
        ends = _ends(line, _NUM)
        assert ends and ends == head[:len(ends)], (line, lines[1])


def test_discrepancy_numbers_stay_under_their_sensor_with_a_long_model_name():
    """'simulation, + pose_error@rigid' is 30 characters: the label column was 28 wide and that
    row's numbers sat two columns right of their headers."""
    disc = {"sensors": ["L1", "L2", "L3", "L4"], "stated_noise_mm": [0.003] * 4,
            "simulated_base_residual_rms_mm": [0.00301, 0.00284, 0.00314, 0.00287],
            "simulated_base_heldout_normal_deg": 0.00569,
            "measured_residual_rms_mm": [0.00709, 0.00766, 0.00719, 0.00636], "measured_heldout_normal_deg": 0.00577,
            "extended_model": "pose_error@rigid+" + "x" * 40,
            "simulated_extended_residual_rms_mm": [0.00747, 0.00807, 0.00745, 0.00704],
            "simulated_extended_heldout_normal_deg": 0.00774}
    lines = discrepancy_lines(disc)
    assert "µm" in lines[0] and len(lines) == 6
    _check_aligned(lines, 4)


def test_structured_cells_are_those_below_the_battery_level_split_over_the_table():
    # 2 variables x 2 sensors: 4 cells, the level 0.01 / 4 = 0.0025
    s = {"d_mm": {"L1": Trend(0.2, 0.002), "L2": Trend(0.1, 0.003)},
         "time_h": {"L1": Trend(0.5, 1e-9), "L2": Trend(0.0, 0.9)}}
    assert structured_cells(s) == [("time_h", "L1", 0.5, 1e-9), ("d_mm", "L1", 0.2, 0.002)]
    assert _grid(s, ("L1", "L2"), s) == (["time_h", "d_mm"], [0])
    nothing = {"d_mm": {"L1": Trend(0.0, 0.5)}}
    assert structured_cells(nothing) == [] and _grid(nothing, ("L1",), nothing) == ([], [])


def test_grid_holds_at_most_the_most_structured_variables_and_only_their_sensors():
    keys = ["d_mm", "incidence_deg", "time_h", "temp_c", "spot_s_mm"]
    s = {k: {"L1": Trend(0.5, 10.0 ** -(3 + j)), "L2": Trend(0.0, 0.5),
             "L3": Trend(0.3, 1e-12 if k == "d_mm" else 0.5)} for j, k in enumerate(keys)}
    cols, rows = _grid(s, ("L1", "L2", "L3"), s)
    assert cols == ["d_mm", "spot_s_mm", "temp_c"][:GRID_MAX_VARIABLES] and rows == [0, 2]


def _figures(diag):
    """The report's figures by file name, each drawn as the page draws it (:func:`fit_to_column`):
    made at the column's width or less (so nothing is squeezed into it), every text inside the
    figure (no label cut at its edge)."""
    from metrology.report.html import COLUMN_IN, fit_to_column

    out = {}
    for name, fig, _ in diagnosis_figures(diag):
        w, h = fig.get_size_inches()
        assert w <= COLUMN_IN + 1e-9, name
        fit_to_column(fig)
        fig.canvas.draw()
        tight = fig.get_tightbbox(fig.canvas.get_renderer())  # inches, every drawn artist
        assert tight.x0 >= -0.01 and tight.y0 >= -0.01 and tight.x1 <= w + 0.01 and tight.y1 <= h + 0.01, (name, tight)
        out[name] = fig
    return out


def _close(figs):
    from metrology.report.style import close

    for fig in figs.values():
        close(fig)


def test_overview_grid_draws_only_the_structured_variables_and_sensors(drift):
    """The drift on L3: one row (L3) and the variables of its significant cells, not 4 x 7
    panels; the structure table holds every cell, the significant ones starred."""
    P = drift.plot_data
    cells = structured_cells(P.structure)
    assert cells and {c[1] for c in cells} == {"L3"}
    figs = _figures(drift)
    axes = figs["residuals_base.png"].axes
    want = list(dict.fromkeys(c[0] for c in cells))[:GRID_MAX_VARIABLES]
    assert len(axes) == len(want) and all(ax.get_title().startswith("L3:") for ax in axes)
    assert "residuals_named.png" in figs
    _close(figs)
    rows = structure_rows(drift)
    assert len(rows) == len(drift.structure_base)
    starred = {(r[0], name) for r in rows for name, c in zip(drift.discrepancy.sensors, r[1:]) if c.endswith("*")}
    assert len(starred) == len(cells) and {s for _, s in starred} == {"L3"}


def test_after_panels_show_heldout_residuals_and_the_text_aligns(measured):
    """The rigid pose error of the bundled run: in-sample its residuals are well below the
    stated noise, held out they are above it. The "after" panels draw the held-out residuals,
    whose RMS is the text's held-out RMS (``heldout.extended_rms_mm``), not the in-sample ones.
    Its text report's row "simulation, + pose_error@rigid" was two columns right of its headers."""
    D = measured.to_dict()
    P = measured.plot_data
    sigma = P.sigma
    insample = np.sqrt(np.nanmean(P.best.fit.residual ** 2, axis=0))
    held = np.sqrt(np.nanmean(P.heldout_after ** 2, axis=0))
    assert np.all(insample < sigma) and np.all(held > sigma)  # the case of the issue
    assert np.isclose(np.sqrt(np.nanmean(P.heldout_after ** 2)), D["heldout"]["extended_rms_mm"], rtol=1e-12)
    assert np.isclose(np.sqrt(np.nanmean(P.heldout_base ** 2)), D["heldout"]["base_rms_mm"], rtol=1e-12)
    figs = _figures(measured)
    assert "residuals_base.png" not in figs  # a random pose error: no trend against any variable
    axes = np.asarray(figs["residuals_named.png"].axes).reshape(-1, 2)
    assert len(axes) == len(P.names)
    for i, (a0, a1) in enumerate(axes):
        np.testing.assert_array_equal(a0.lines[0].get_ydata(), 1e3 * P.heldout_base[:, i])
        np.testing.assert_array_equal(a1.lines[0].get_ydata(), 1e3 * P.heldout_after[:, i])
        assert a1.get_title() == f"after: RMS {1e3 * held[i]:.2f} µm"
    _close(figs)
    # the text report of the same run (one diagnosis a test: a few seconds each): its tables'
    # numbers under their headers, micrometres spelt one way
    text = report_text(measured)
    assert not re.search(r"\bum\b", text) and "µm" in text
    lines = text.splitlines()
    k = next(i for i, x in enumerate(lines) if x.startswith("discrepancy"))
    block = lines[k:lines.index("", k)]
    assert any("simulation, + pose_error@rigid" in x for x in block)
    _check_aligned(block, len(measured.plot_data.names))
    # the steps of the selection: each step's numbers end in the same columns
    k = next(i for i, x in enumerate(lines) if x.startswith("residuals after each step"))
    steps = lines[k + 1:lines.index("", k)]
    assert len(steps) >= 2 and len({tuple(_ends(x, _NUM)) for x in steps}) == 1

"""The head's spin with the panel known (metrology.measure.spin): from the pose, a convention the redundant
reading confirms, or a U95 over every spin; on logs whose spin is free, drawn by the forward simulator."""

from __future__ import annotations

import json

import numpy as np
import pytest
from dataclasses import replace

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.sim.forward.log import simulate_cell
from metrology.sim.forward.log_spec import LogSpec
from metrology.sim.forward.panels import make_panel
from tests.measure.panel_fixtures import panel_mesh

TABLE6 = data_path("measured/nominal.toml")


def _measured(n_sensors, spin_deg, stated=None, holes=1200, seed=5, pose=False):
    """A barrel R 600 (axis at 30 deg) drilled by the Table 6 head (or its first 3 sensors) whose spin is
    uniform within +-spin_deg; measured with the CAD, the log without (or with) its commanded pose."""
    from metrology.measure.holes import measure_batch

    lay, table, settings, ch = _inputs(n_sensors, spin_deg, stated, holes, seed, pose)
    b = measure_batch(lay, table, settings)
    U = np.radians(b.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
    ok = np.isfinite(b.angle_before) & np.isfinite(U)
    covered = np.abs(b.angle_before - ch.true_angle)[ok] <= U[ok]
    return b, covered


def _inputs(n_sensors, spin_deg, stated=None, holes=1200, seed=5, pose=False, radius_mm=600.0):
    """``(layout, log table, Settings, the forward simulator's cell)`` of :func:`_measured`."""
    import pyarrow as pa

    from metrology.io.holelog_schema import CELL, PANEL, TIME_S
    from metrology.jobs.measure_panel import panel_hole_surfaces
    from metrology.measure.holes import Settings
    from metrology.measure.panel import HoleTable
    from metrology.panel.mesh import Panel

    lay = load_layout(TABLE6)
    if n_sensors == 3:
        lay = lay.subset(("L1", "L2", "L3"))
    panel = make_panel("cylinder", radius_mm, axis=(np.cos(0.5), np.sin(0.5), 0.0))
    spec = LogSpec(lay, lay, panel, resolution_mm=0.0, patch_half_mm=40.0, spin_rad=np.radians(spin_deg))
    ch = next(simulate_cell(spec, seed, 0, holes, holes))
    ids = tuple(f"h{i}" for i in range(holes))
    table = HoleTable(ids, ch.drill_point, -panel.normal_at(ch.drill_point), "holes.csv")
    surf = panel_hole_surfaces(Panel(panel_mesh(panel, half_mm=150.0, step_mm=3.0)), table, 55.0,
                               spin=np.radians(2.0 if stated is None else stated))
    surf = replace(surf, spin_stated=stated is not None)
    cols = {"hole_id": list(ids), CELL: ["C1"] * holes, PANEL: ["P1"] * holes,
            TIME_S: (1.8e9 + np.arange(holes)).astype(float)}
    for j, nm in enumerate(lay.names):
        cols[f"d_{nm}"] = ch.d[:, j]
    if pose:
        for j, ax in enumerate("xyz"):
            cols[f"pose_r{ax}_deg"] = np.degrees(ch.pose_rotvec[:, j])
            cols[f"pose_{ax}_mm"] = ch.pose_origin[:, j]
    return lay, pa.table(cols), Settings(surfaces=surf), ch


def test_a_holes_figures_do_not_depend_on_the_holes_beside_it_when_some_spins_are_read_and_some_not():
    """A batch where the spin is read at some holes and left at the convention at others (R 150, spin within
    +-10 deg): each hole's angle and U95 are the same as in the batch taken in reverse order (the read holes' and the
    convention's fits put back in hole order, not shifted onto a neighbour's)."""
    from metrology.measure import spin
    from metrology.measure.holes import measure_batch

    lay, table, settings, _ = _inputs(4, 10.0, stated=2.0, holes=60, radius_mm=150.0)
    calls = []
    fits = spin._fits
    try:
        spin._fits = lambda fit, u, c, *a: calls.append((len(u), len(c))) or fits(fit, u, c, *a)
        b = measure_batch(lay, table, settings)
    finally:
        spin._fits = fits
    assert calls and all(nu and nc for nu, nc in calls), calls  # both kinds in one call: what the test is about
    back = measure_batch(lay, table.take(np.arange(len(table))[::-1]), settings)
    for name in ("angle_deg", "U95_angle_deg"):
        got = b.columns.column(name).to_numpy(zero_copy_only=False)
        rev = back.columns.column(name).to_numpy(zero_copy_only=False)[::-1]
        np.testing.assert_array_equal(got, rev, err_msg=name)


def test_four_sensors_free_spin_no_pose_the_convention_is_refused_where_it_fails_and_u95_holds():
    b, covered = _measured(4, 180.0)
    assert b.spin_free.sum() > 0.5 * len(b)  # a free spin breaks the convention at most holes
    assert covered.mean() > 0.92, covered.mean()
    reasons = b.columns.column("reason").to_pylist()
    free = np.flatnonzero(b.spin_free)
    assert all("covers every spin" in reasons[i] and ("not the cell's convention" in reasons[i] or  # refuted
                                                      "cannot tell it from a spin of" in reasons[i])  # or its alias
               for i in free[:50])
    assert np.mean(b.status != 3) > 0.95  # measured, not refused as disagreeing


def test_four_sensors_within_a_stated_convention_keep_it():
    """Stated (``--spin-deg``): the convention is kept where the redundant reading does not refute it. Unstated, the
    reading's alias spin (near 33 deg on this barrel, whose axis lies 30 deg off the head's x) tilts the normal
    otherwise: tests/measure/test_spin_alias.py."""
    b, covered = _measured(4, 2.0, stated=2.0)
    assert b.spin_free.sum() <= 0.01 * len(b)
    assert b.on_convention.sum() >= 0.99 * len(b)
    assert covered.mean() > 0.92, covered.mean()


@pytest.mark.parametrize("stated", [None, 2.0])
def test_three_sensors_rest_on_a_stated_convention_else_a_bound_over_every_spin(stated):
    b, covered = _measured(3, 180.0, stated=stated)
    if stated is None:  # no redundancy, nothing stated: every hole judged over every spin, and covered
        assert b.spin_free.all() and not b.on_convention.any()
        assert covered.mean() > 0.92, covered.mean()
    else:  # the convention is the user's statement: taken, and named in the summary's count
        assert b.on_convention.all() and not b.spin_free.any()


def test_with_the_pose_nothing_rests_on_the_convention():
    b, covered = _measured(3, 180.0, pose=True)
    assert not b.on_convention.any() and not b.spin_free.any()
    assert covered.mean() > 0.92, covered.mean()


def test_the_cli_measures_a_free_spin_log_without_pose_and_counts_the_holes(tmp_path):
    from typer.testing import CliRunner

    from cli.main import app

    panels = data_path("panels")
    log = tmp_path / "wing.csv"
    # in the test's process (a Python process of its own cost ~1 s of CPU, and this test is not about the process)
    r = CliRunner().invoke(app, ["simulate-log", "--out", str(log), "--holes", "300", "--seed", "4", "--panel",
                                 str(panels / "wing.stl"), "--points", str(panels / "wing.holes.csv"), "--true-layout",
                                 str(TABLE6), "--layout", str(TABLE6), "--spin-deg", "180", "--no-truth"])
    assert r.exit_code == 0, r.output
    import pyarrow.csv as pcsv

    t = pcsv.read_csv(log)
    pcsv.write_csv(t.drop([c for c in t.column_names if c.startswith("pose_")]), log)
    res = CliRunner().invoke(app, ["measure", str(log), "--layout", str(TABLE6), "--panel", str(panels / "wing.stl"),
                                   "--points", str(panels / "wing.holes.csv"), "--json"])
    assert res.exit_code in (0, 1), res.output
    doc = json.loads(res.stdout[res.stdout.index("{"):])
    cv = doc["curvature"]
    assert cv["spin_stated"] is False
    assert cv["spin_free_holes"] > 0 and cv["spin_free_holes"] + cv["spin_on_convention_holes"] >= 0.9 * 300
    names = [c["name"] for c in doc["verdict"]["checks"]]
    assert any("spin not known" in n for n in names)

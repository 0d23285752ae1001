"""metro measure --panel/--points on the bundled CAD panels (metrology/data/panels), each log drilled
by the forward simulator on the panel's own surface (simulate-log --panel KIND --points TABLE)."""

import csv
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path

runner = CliRunner()
TABLE6 = str(data_path("measured", "nominal.toml"))


def _read(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _drill_and_measure(tmp_path, kind, holes, extra=()):
    """simulate-log on KIND (the bundled hole table cycled to ``holes`` holes), then measure it with
    the bundled panel and table; returns (measured rows, truth rows by hole_id, measure's JSON)."""
    log = tmp_path / f"{kind}.csv"
    pts = [] if kind == "flat" else ["--points", str(data_path("panels", f"{kind}.holes.csv"))]
    r = runner.invoke(app, ["simulate-log", "--panel", kind, *pts, "--holes", str(holes), "--seed", "3",
                            "--layout", TABLE6, "--true-layout", TABLE6, "--out", str(log), *extra])
    assert r.exit_code == 0, r.output
    out = tmp_path / f"{kind}.m.csv"
    panel = ["--min-radius-mm", "inf"] if kind == "flat" else ["--panel", str(data_path("panels", f"{kind}.stl"))]
    r = runner.invoke(app, ["measure", str(log), "--layout", TABLE6, *panel, *pts, "--out", str(out), "--json"])
    assert r.exit_code in (0, 1), r.output
    truth = {t["hole_id"]: t for t in _read(tmp_path / f"{kind}.truth.csv")}
    return _read(out), truth, json.loads(r.stdout)


def test_a_cycled_hole_table_is_measured_on_every_pass(tmp_path):
    """60 holes from a 25-hole table: passes 2 and 3 are H0001#2 ..., their point_id the table's id."""
    rows, truth, _ = _drill_and_measure(tmp_path, "wing", 60)
    assert len(rows) == 60
    assert sum("#" in r["hole_id"] for r in rows) == 35
    assert [r["status"] for r in rows if r["status"] == "not_measured"] == []
    assert all(r["angle_deg"] != "" for r in rows)
    # each pass measured against its own truth
    err = [abs(float(r["angle_deg"]) - float(truth[r["hole_id"]]["true_angle_deg"])) for r in rows]
    assert np.median(err) < 0.01


def _median_error(rows, truth):
    return np.median([abs(float(r["angle_deg"]) - float(truth[r["hole_id"]]["true_angle_deg"])) for r in rows])


@pytest.fixture(scope="module")
def flat_error(tmp_path_factory):
    rows, truth, _ = _drill_and_measure(tmp_path_factory.mktemp("flat"), "flat", 200)
    return _median_error(rows, truth)


@pytest.mark.parametrize("kind", ["wing", "barrel", "nacelle", "saddle"])
def test_the_measured_angle_on_a_bundled_panel_is_as_good_as_on_a_flat_one(tmp_path, kind, flat_error):
    """Median |measured - true angle| within 2x the flat panel's (measured 1.1-1.2x on 200 holes;
    the micro-plane alone is 14-17x on a wing or a concave barrel)."""
    rows, truth, _ = _drill_and_measure(tmp_path, kind, 200)
    assert all(r["status"] != "not_measured" for r in rows)
    err = _median_error(rows, truth)
    assert err <= 2.0 * flat_error, (kind, err, flat_error)


def _col(rows, key):
    return np.array([float(r[key]) if r[key] != "" else np.nan for r in rows])


def _off_cad(tmp_path, off_cad, kind="wing"):
    """A log drilled on KIND off its CAD by ``off_cad``, the robot's orientation error small (0-0.02 deg:
    the commanded pose is then the head's to within it), measured with the CAD panel."""
    extra = ["--angle-deg", "0,0.02"] + (["--off-cad", off_cad] if off_cad else [])
    rows, truth, js = _drill_and_measure(tmp_path, kind, 50, extra)
    t = [truth[r["hole_id"]] for r in rows]
    _off_cad.json = js
    return rows, t


@pytest.mark.parametrize("kind", ["wing", "nacelle"])
def test_a_panel_shifted_1mm_along_its_normal_shows_in_cad_offset(tmp_path, kind):
    rows, t = _off_cad(tmp_path, "shift:0,0,1", kind)
    off, true = _col(rows, "cad_offset_mm"), _col(t, "cad_offset_mm")
    ok = np.isfinite(off)
    assert ok.mean() > 0.9
    # measured 1.0002 / 1.0019 median against the truth's 0.9997 / 0.9972, worst hole 0.009 mm off
    assert np.max(np.abs(off[ok] - true[ok])) < 0.03
    assert abs(np.median(off[ok]) - 1.0) < 0.02
    # the summary and the verdict name it with its size (information, not a gate)
    cv = _off_cad.json["curvature"]
    assert cv["cad_off_holes"] >= 0.9 * cv["cad_checked"] > 0
    assert abs(cv["cad_offset_mean_abs_mm"] - 1.0) < 0.02 and abs(cv["cad_offset_max_mm"] - 1.0) < 0.03
    named = [c for c in _off_cad.json["verdict"]["checks"] if c["name"].startswith("panel against its CAD")]
    assert len(named) == 1 and "+1.00" in named[0]["name"]


def test_on_its_cad_the_offset_and_angle_are_nothing(tmp_path):
    rows, _ = _off_cad(tmp_path, None)
    off, ang = _col(rows, "cad_offset_mm"), _col(rows, "normal_vs_cad_deg")
    assert np.all(np.isfinite(off)) and np.all(np.isfinite(ang))
    assert np.max(np.abs(off)) < 0.01
    # the robot's orientation error (0-0.02 deg) is all the angle holds
    assert np.max(ang) < 0.05
    assert _off_cad.json["curvature"]["cad_off_holes"] == 0


def test_a_dent_shows_in_cad_offset_and_normal_vs_cad(tmp_path):
    """A dent 0.2 mm deep, 100 mm wide at the wing's centre: the holes on its flank turned by 0.36 deg,
    the centre 0.2 mm low. The readings see it averaged over their footprint (measured: 0.20 deg on
    the flank, -0.09 mm at the centre); holes beside it read nothing."""
    rows, t = _off_cad(tmp_path, "dent:0.2@0,0")
    off, ang = _col(rows, "cad_offset_mm"), _col(rows, "normal_vs_cad_deg")
    toff, tang = _col(t, "cad_offset_mm"), _col(t, "cad_angle_deg")
    flank = (tang > 0.3) & np.isfinite(ang)
    assert flank.sum() >= 4
    assert np.all((ang[flank] > 0.12) & (ang[flank] < 0.5)), ang[flank]
    centre = (toff < -0.15) & np.isfinite(off)
    assert centre.sum() >= 1 and np.all(off[centre] < -0.05), off[centre]
    clear = (np.abs(toff) < 1e-3) & (tang < 1e-3) & np.isfinite(off)
    assert np.max(np.abs(off[clear])) < 0.03 and np.max(ang[clear]) < 0.1


def test_without_pose_columns_no_cad_columns(tmp_path):
    rows, _, _ = _drill_and_measure(tmp_path, "wing", 25)
    import pyarrow.csv as pc
    log = tmp_path / "wing.csv"
    tab = pc.read_csv(log)
    tab = tab.drop([c for c in tab.column_names if c.startswith("pose_")])
    pc.write_csv(tab, tmp_path / "nopose.csv")
    out = tmp_path / "nopose.m.csv"
    r = runner.invoke(app, ["measure", str(tmp_path / "nopose.csv"), "--layout", TABLE6,
                            "--panel", str(data_path("panels", "wing.stl")),
                            "--points", str(data_path("panels", "wing.holes.csv")), "--out", str(out)])
    assert r.exit_code in (0, 1), r.output
    got = _read(out)
    assert "cad_offset_mm" not in got[0] and "normal_vs_cad_deg" not in got[0]
    assert all(g["status"] != "not_measured" for g in got)


@pytest.mark.slow  # the STEP's tessellation and surfaces: ~2 min on a loaded 2-core machine
def test_the_panels_study_runs_and_metros_normal_drills_the_nacelle_as_flat(tmp_path, monkeypatch):
    """benchmarks/study_measure.py --panel-known on the Table 6 head, 2 calibrations x 60 holes, flat,
    nacelle and the wing as STEP: the rows, and the holes drilled with metro's normal in the loop on the
    nacelle (R 400 x 1200) within 1.5x flat, the micro-plane's many times that (measured at 40 x 500,
    seed 11: docs/measure.md)."""
    import importlib.util
    from pathlib import Path

    pytest.importorskip("cascadio")
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "study_measure.py"
    monkeypatch.syspath_prepend(str(path.parent))  # its _one_blas_thread
    spec = importlib.util.spec_from_file_location("study_measure", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    out = tmp_path / "s.json"
    mod.main(["--panel-known", "--heads", "table6", "--panels", "flat,nacelle,wing (STEP)", "--calibrations", "2",
              "--holes", "60", "--seed", "3", "--json", str(out)])
    rows = {r["panel"]: r for r in json.loads(out.read_text())["rows"]}
    assert set(rows) == {"flat", "nacelle", "wing (STEP)"}
    flat = rows["flat"]["median_drill_metro_deg"]
    assert rows["nacelle"]["median_drill_metro_deg"] <= 1.5 * flat
    assert rows["nacelle"]["median_drill_plane_deg"] > 5 * flat
    for r in rows.values():
        assert r["holes"] == 120 and 0.85 <= r["coverage_before"] <= 1.0


@pytest.mark.slow  # reading the STEP (OpenCASCADE's 1 um tessellation): ~1 min on a loaded 2-core machine
def test_the_bundled_step_wing_is_the_generated_wing():
    """metrology/data/panels/wing.step (fixtures/make_wing_step.py, a B-spline face) read as metro reads a
    STEP panel: at the bundled holes its normals and shape operators are the generated wing's
    (metrology.sim.forward.shapes) from the exact B-rep, the bundled mesh's to its faceting."""
    pytest.importorskip("cascadio")
    from metrology.jobs.measure_panel import panel_hole_surfaces
    from metrology.measure.panel import read_hole_table
    from metrology.panel.mesh import load_panel
    from metrology.sim.forward.shapes import generated_panel

    table = read_hole_table(data_path("panels", "wing.holes.csv"))
    wing = generated_panel("wing")
    k_true = np.linalg.eigvalsh(wing.shape_at(table.point))[:, [2, 1]]  # k1 >= k2 (the normal's 0 first)
    n_true = wing.normal_at(table.point)
    # measured: the STEP (its B-rep, the step-exact extra) within 2.3e-6 deg and 1.1e-8 /mm; its
    # tessellation fitted as a mesh 0.012 deg and 1.1e-7 /mm; the 10 mm STL 7e-5 deg and 1.8e-6 /mm
    step = load_panel(str(data_path("panels", "wing.step")))
    assert step.surface is not None, "the step-exact extra reads the B-rep"
    for panel, tol_k, tol_deg, src in ((step, 1e-6, 1e-4, "B-rep (exact STEP faces)"),
                                       (load_panel(str(data_path("panels", "wing.stl"))), 5e-6, 0.001, "mesh")):
        s = panel_hole_surfaces(panel, table, 55.0)
        assert src in s.source
        assert all(p == "" for p in s.problem)
        assert np.degrees(np.arccos(np.clip(np.abs(np.sum(s.normal * n_true, 1)), -1, 1))).max() < tol_deg
        np.testing.assert_allclose(s.k, k_true, atol=tol_k)
        np.testing.assert_allclose(s.shape, wing.shape_at(table.point), atol=tol_k)  # one sign convention
    # without the B-rep the STEP's tessellation is fitted as a mesh: to its faceting only
    step.surface = None
    s = panel_hole_surfaces(step, table, 55.0)
    assert "mesh" in s.source
    assert np.degrees(np.arccos(np.clip(np.abs(np.sum(s.normal * n_true, 1)), -1, 1))).max() < 0.02


def test_the_robots_own_tilt_counts_no_hole_off_its_cad(tmp_path):
    """A default log (true angles 0.5-5 deg before the adjustment: the robot's orientation error) on
    a panel that is its CAD: the angle against the CAD is large, yet no hole is counted off it."""
    from cli.main import app
    from typer.testing import CliRunner

    from metrology.io.data import data_path

    runner = CliRunner()
    panels = data_path("panels")
    log = tmp_path / "w.csv"
    # the head as its layout says (without --true-layout a covariance-less layout is drawn off by
    # DEFAULT_LAYOUT_ERROR, unexplained in U95: its redundant misfit, near 6 sigma on a hole or two, is not what this checks)
    nominal = str(data_path("measured", "nominal.toml"))
    r = runner.invoke(app, ["simulate-log", "--layout", nominal, "--true-layout", nominal, "--panel", "wing",
                            "--points", str(panels / "wing.holes.csv"), "--holes", "200", "--out", str(log)])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["measure", str(log), "--layout", nominal, "--panel",
                            str(panels / "wing.stl"), "--points", str(panels / "wing.holes.csv"), "--json"])
    assert r.exit_code in (0, 1), r.output
    cv = json.loads(r.stdout)["curvature"]
    assert cv["cad_checked"] == 200 and cv["normal_vs_cad_max_deg"] > 0.5
    assert cv["cad_off_holes"] == 0 and abs(cv["cad_offset_max_mm"]) < 0.05


def _wing_seed2(tmp_path, layout, measure_layout=None, panel=True):
    """The 100-hole wing log of seed 2 drawn with ``layout`` (the head drawn from it: its covariance,
    else the simulator's default 15-30 um / 0.015-0.03 deg off it), measured with ``measure_layout``."""
    wing, pts = str(data_path("panels", "wing.stl")), str(data_path("panels", "wing.holes.csv"))
    log = tmp_path / "wing2.csv"
    r = runner.invoke(app, ["simulate-log", "--layout", str(layout), "--panel", wing, "--points", pts,
                            "--holes", "100", "--seed", "2", "--out", str(log)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "wing2.m.csv"
    r = runner.invoke(app, ["measure", str(log), "--layout", str(measure_layout or layout), "--out", str(out),
                            *(["--panel", wing, "--points", pts] if panel else [])])
    truth = {t["hole_id"]: t for t in _read(tmp_path / "wing2.truth.csv")}
    return r, (_read(out) if out.exists() else None), truth


def test_a_wing_log_from_a_head_within_its_calibration_is_never_refused(tmp_path):
    """The reported "wing, 100 holes, --seed 2, exit 2": with a layout that states its calibration's
    covariance (the head drawn from it) the same log is measured, every hole, its U95 covering."""
    from metrology.io.layout import load_layout, save_layout

    nominal = load_layout(TABLE6)
    C = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, nominal.n))
    save_layout(nominal.with_params(nominal.zero, nominal.direction, covariance=C), tmp_path / "cal.toml")
    r, rows, truth = _wing_seed2(tmp_path, tmp_path / "cal.toml")
    assert r.exit_code == 0, r.output
    assert [x["status"] for x in rows] == ["conforms"] * 100
    err = np.array([abs(float(x["angle_after_deg"]) - float(truth[x["hole_id"]]["true_after_deg"])) for x in rows])
    assert np.mean(err <= np.array([float(x["U95_after_deg"]) for x in rows])) >= 0.9


def test_a_nominal_layout_on_a_head_30um_off_it_is_refused_with_the_panel_known_and_rightly(tmp_path):
    """The same seed drawn with the nominal layout (no covariance: the simulator's head 15-30 um and
    0.015-0.03 deg off it): with the panel known the misfit (~20 um against a 3 um sigma) refuses the
    layout, exit 2; a true refusal: measured without the panel, the misfit is beyond the reading noise at
    every hole, and rule 2b (issue 51 item 5) widens U95 to cover one sensor's offset (the head's error among
    them): the tight U95 of the reading noise alone, which would miss the truth, is not claimed."""
    r, rows, _ = _wing_seed2(tmp_path, TABLE6)
    assert r.exit_code == 2 and rows is None
    assert "a nominal layout, not its calibration?" in r.output
    r, rows, truth = _wing_seed2(tmp_path, TABLE6, panel=False)
    assert r.exit_code == 0, r.output
    err = np.array([abs(float(x["angle_after_deg"]) - float(truth[x["hole_id"]]["true_after_deg"])) for x in rows])
    u = np.array([float(x["U95_after_deg"]) for x in rows])
    assert np.mean(err <= u) >= 0.95 and np.median(u) > 5 * np.median(err)
    assert all("one sensor's offset" in x["reason"] for x in rows if x["status"] != "conforms")

"""A panel and its hole table in inches or metres (together, or the table alone) are refused by
``metro measure`` and ``metro simulate-log`` with one line naming the likely unit; ``--units``
reads them (issue 51, item 1 and 2)."""

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from metrology.io.panel_units import check_panel_units, nearest_spacing

runner = CliRunner()
TABLE6 = str(data_path("measured", "nominal.toml"))
R = 1500.0  # the skin's radius, mm


def _skin(folder, unit, scale):
    """A 1200 x 800 mm paraboloid skin (R 1500 mm) and its 77 holes 100 mm apart, written in ``unit``."""
    import trimesh

    gx, gy = np.arange(-600, 601, 20.0), np.arange(-400, 401, 20.0)
    X, Y = np.meshgrid(gx, gy, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), -(X.ravel() ** 2 + Y.ravel() ** 2) / (2 * R)], 1)
    m = len(gy)
    i, j = np.meshgrid(np.arange(len(gx) - 1), np.arange(m - 1), indexing="ij")
    a = (i * m + j).ravel()
    F = np.concatenate([np.stack([a, a + m, a + m + 1], 1), np.stack([a, a + m + 1, a + 1], 1)])
    mesh, table = folder / f"skin_{unit}.stl", folder / f"skin_{unit}.holes.csv"
    trimesh.Trimesh(V * scale, F, process=False).export(str(mesh))
    with open(table, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["hole_id", "x", "y", "z", "i", "j", "k"])
        k = 0
        for x in np.arange(-500, 501, 100.0):
            for y in np.arange(-300, 301, 100.0):
                n = np.array([x / R, y / R, 1.0])
                n /= np.linalg.norm(n)
                k += 1
                w.writerow([f"H{k:04d}", x * scale, y * scale, -(x * x + y * y) / (2 * R) * scale, *(-n)])
    return str(mesh), str(table)


@pytest.fixture(scope="module")
def skins(tmp_path_factory):
    folder = tmp_path_factory.mktemp("skins")
    files = {u: _skin(folder, u, s) for u, s in (("mm", 1.0), ("in", 1 / 25.4), ("m", 1e-3))}
    log = folder / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--panel", files["mm"][0], "--points", files["mm"][1], "--holes", "40",
                            "--seed", "3", "--layout", TABLE6, "--true-layout", TABLE6, "--out", str(log)])
    assert r.exit_code == 0, r.output
    return folder, files, str(log)


def _measure(log, *args):
    return runner.invoke(app, ["measure", log, "--layout", TABLE6, *args])


@pytest.mark.parametrize("unit, word", [("in", "inches"), ("m", "metres")])
def test_a_panel_and_its_table_in_one_wrong_unit_are_refused(skins, unit, word):
    folder, files, log = skins
    out = folder / f"m_{unit}.csv"
    r = _measure(log, "--panel", files[unit][0], "--points", files[unit][1], "--out", str(out))
    assert r.exit_code == 2, r.output
    err = r.output.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "Traceback" not in r.output
    assert f"look like {word}" in err[0] and f"--units {unit}" in err[0] and "footprint" in err[0]
    assert not out.exists()


def test_the_table_alone_in_inches_is_refused_naming_the_spacing(skins):
    folder, files, log = skins
    r = _measure(log, "--points", files["in"][1], "--out", str(folder / "p.csv"))
    assert r.exit_code == 2, r.output
    assert "3.94 mm apart" in r.output and "inches" in r.output and "--units in" in r.output


def test_a_table_in_inches_on_a_panel_in_mm_asks_to_convert_the_table(skins):
    folder, files, log = skins
    r = _measure(log, "--panel", files["mm"][0], "--points", files["in"][1], "--out", str(folder / "q.csv"))
    assert r.exit_code == 2, r.output
    assert "hole table is not in mm, it looks like inches (the panel like mm)" in r.output


def test_units_in_measures_the_inch_files_as_the_mm_ones(skins):
    folder, files, log = skins
    rows = {}
    for unit, extra in (("mm", []), ("in", ["--units", "in"])):
        out = folder / f"u_{unit}.csv"
        r = _measure(log, "--panel", files[unit][0], "--points", files[unit][1], *extra, "--out", str(out))
        assert r.exit_code in (0, 1), r.output
        with open(out, newline="") as fh:
            rows[unit] = list(csv.DictReader(fh))
    a = np.array([float(x["angle_deg"]) for x in rows["mm"]])
    b = np.array([float(x["angle_deg"]) for x in rows["in"]])
    assert np.all(np.isfinite(a)) and np.allclose(a, b, atol=1e-4)
    # the wrong unit given: refused, the words say --units was given
    r = _measure(log, "--panel", files["m"][0], "--points", files["m"][1], "--units", "in")
    assert r.exit_code == 2 and "--units in" in r.output and "check the files' unit" in r.output


def test_simulate_log_refuses_the_inch_panel(skins, tmp_path):
    _, files, _ = skins
    r = runner.invoke(app, ["simulate-log", "--panel", files["in"][0], "--points", files["in"][1], "--holes", "10",
                            "--layout", TABLE6, "--out", str(tmp_path / "x.csv")])
    assert r.exit_code == 2, r.output
    assert "look like inches" in r.output and not (tmp_path / "x.csv").exists()


def test_the_rule_on_numbers():
    """The rule alone: mm passes; inches, metres caught; a log's commanded positions far from the table's
    points name the table's unit even where its spacing and the panel pass."""
    g = np.stack(np.meshgrid(np.arange(0, 2001, 200.0), np.arange(0, 1001, 200.0)), -1).reshape(-1, 2)
    T = np.c_[g, np.zeros(len(g))]
    assert nearest_spacing(T) == pytest.approx(200.0)
    ok = dict(footprint_mm=26.6, standoff_mm=50.0)
    assert check_panel_units(**ok, panel_extent=(2100, 1100, 10), table_points=T) is None
    assert "inches" in check_panel_units(**ok, panel_extent=np.array((2100, 1100, 10)) / 25.4,
                                         table_points=T / 25.4)
    poses = T + [0, 0, 50.0]
    assert check_panel_units(**ok, table_points=T, pose_points=poses) is None
    line = check_panel_units(**ok, table_points=T / 25.4, pose_points=poses)  # 7.9 mm apart: spacing passes
    assert line is not None and "commanded positions" in line and "inches" in line


def test_a_log_none_of_whose_holes_is_in_the_table_is_refused(skins):
    """Item 4: every hole would be not_measured, "off its CAD"; refused, exit 2, nothing written."""
    folder, files, log = skins
    with open(log, newline="") as fh:
        rows = list(csv.reader(fh))
    at = [rows[0].index(k) for k in ("hole_id", "point_id")]
    for r in rows[1:]:
        for j in at:
            r[j] = "X" + r[j]
    other = folder / "other.csv"
    with open(other, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    out, qif, rep = folder / "o.csv", folder / "o.qif", folder / "o.html"
    r = _measure(str(other), "--panel", files["mm"][0], "--points", files["mm"][1], "--out", str(out),
                 "--qif", str(qif), "--report", str(rep))
    assert r.exit_code == 2, r.output
    assert "none of its 40 holes is in the hole table" in r.output and "'XH0001'" in r.output
    assert not out.exists() and not qif.exists() and not rep.exists()


def test_report_and_qif_record_the_panel_and_table_and_map_the_holes(skins):
    """Item 6: the inputs with their SHA-256 (report and QIF), the panel map, the panel's own words."""
    import hashlib
    import re

    folder, files, log = skins
    rep, qif = folder / "r.html", folder / "r.qif"
    r = _measure(log, "--panel", files["mm"][0], "--points", files["mm"][1], "--out", str(folder / "r.csv"),
                 "--report", str(rep), "--qif", str(qif))
    assert r.exit_code in (0, 1), r.output
    from html import unescape

    html = unescape(rep.read_text(encoding="utf-8"))
    for f in files["mm"]:
        digest = hashlib.sha256(open(f, "rb").read()).hexdigest()
        assert digest in html
        assert digest in qif.read_text(encoding="utf-8")
    assert "The panel's holes coloured by their judged angle" in html
    assert re.search(r"uncertainty: [^\n]*each hole's curvature from panel \S*skin_mm.stl", html)
    assert "each hole's surface is taken from panel" in html  # what the data could not determine
    assert not re.search(r"curvature bias for a panel radius", html)


@pytest.mark.parametrize("length", [2.0, 1.3])
def test_a_feed_vector_not_of_unit_length_is_refused(skins, tmp_path, length):
    """Issue 51, item 14: a feed of length 2 or 1.3 was normalised without a word."""
    folder, files, log = skins
    with open(files["mm"][1], newline="") as fh:
        rows = list(csv.reader(fh))
    rows[3][4:7] = [f"{float(v) * length:.9f}" for v in rows[3][4:7]]
    bad = tmp_path / "bad.csv"
    with open(bad, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    r = _measure(log, "--panel", files["mm"][0], "--points", str(bad), "--out", str(tmp_path / "o.csv"))
    assert r.exit_code == 2, r.output
    assert f"line 4: hole H0003: feed direction i,j,k has length {length:g}" in r.output


def test_a_narrow_deep_panel_is_not_read_as_inches():
    """Issue 53 against issue 51's rule: a leading edge or tube (R 20: 40 mm across, 20 deep, 320 long) is narrower
    than the footprint but deep, and drilled: not refused as inches; the same box flat (a skin in inches) is."""
    ok = dict(footprint_mm=26.6, standoff_mm=50.0)
    assert check_panel_units(**ok, panel_extent=(320.0, 40.0, 20.0)) is None
    line = check_panel_units(**ok, panel_extent=(320.0, 40.0, 2.0))
    assert line is not None and "narrower" in line


def _log_in(log, folder, unit, scale, fmt="csv"):
    """The simulated log with its commanded positions ``pose_{x,y,z}_mm`` written in ``unit`` (a CSV file, or a hive
    folder of Parquet files)."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pcsv

    t = pcsv.read_csv(log)
    t = pa.table({n: pc.divide(t[n], scale) if n in ("pose_x_mm", "pose_y_mm", "pose_z_mm") else t[n]
                  for n in t.column_names})
    if fmt == "csv":
        out = folder / f"log_pose_{unit}.csv"
        pcsv.write_csv(t, out)
        return str(out)
    import pyarrow.parquet as pq

    out = folder / f"hive_pose_{unit}"
    for i, half in enumerate((t.slice(0, 20), t.slice(20))):
        (out / f"cell=C1/part={i}").mkdir(parents=True, exist_ok=True)
        pq.write_table(half.drop(["cell"]), out / f"cell=C1/part={i}/log.parquet")
    return str(out)


@pytest.mark.parametrize("unit, scale, word", [("in", 25.4, "inches"), ("m", 1000.0, "metres")])
def test_a_log_whose_commanded_positions_are_in_another_unit_is_refused(skins, unit, scale, word):
    """Item 1: panel and table in mm, the log's pose_*_mm in inches or metres: refused naming the log and the fix."""
    folder, files, log = skins
    bad = _log_in(log, folder, unit, scale)
    out = folder / f"pose_{unit}.csv"
    r = _measure(bad, "--panel", files["mm"][0], "--points", files["mm"][1], "--out", str(out))
    assert r.exit_code == 2, r.output
    err = r.output.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {bad}: the log's commanded positions lie a median")
    assert f"(pose_x_mm, pose_y_mm, pose_z_mm) look like {word}: write them in mm" in err[0]
    assert not out.exists()


@pytest.mark.parametrize("unit, scale, word", [("in", 25.4, "inches"), ("m", 1000.0, "metres")])
def test_panel_table_and_log_in_one_wrong_unit_name_both_fixes(skins, unit, scale, word):
    """All three in one wrong unit: the files' fix (--units) and the positions' (they are not scaled by it), at once;
    with --units the positions' alone."""
    folder, files, log = skins
    bad = _log_in(log, folder, unit, scale)
    r = _measure(bad, "--panel", files[unit][0], "--points", files[unit][1], "--out", str(folder / "x.csv"))
    assert r.exit_code == 2, r.output
    assert f"they look like {word}: give --units {unit}" in r.output
    assert f"look like {word} too: write them in mm" in r.output
    r = _measure(bad, "--panel", files[unit][0], "--points", files[unit][1], "--units", unit)
    assert r.exit_code == 2, r.output
    assert f"(--units {unit})" in r.output and f"look like {word}: write them in mm" in r.output


def test_a_hive_log_in_inches_is_refused_on_dask(skins, tmp_path):
    """The same check on a hive folder of Parquet files, run by Dask: refused before anything is written."""
    folder, files, log = skins
    bad = _log_in(log, folder, "in", 25.4, fmt="hive")
    out = tmp_path / "out"
    r = _measure(bad, "--panel", files["mm"][0], "--points", files["mm"][1], "--out", str(out), "--workers", "1")
    assert r.exit_code == 2, r.output
    assert "look like inches: write them in mm" in r.output and not out.exists()
    ok = _log_in(log, folder, "mm", 1.0, fmt="hive")  # the same folder in mm passes the rule
    from metrology.io.holelog import open_log
    from metrology.io.holelog_sample import commanded_positions

    keys, xyz = commanded_positions(open_log(ok, ("L1", "L2", "L3", "L4")))
    assert len(keys) == 40 and keys[0] == "H0001" and np.all(np.isfinite(xyz))
    assert check_panel_units(26.6, 50.0, table_points=xyz + [0, 0, -50.0], pose_points=xyz) is None


def test_another_heads_nominal_layout_is_refused_in_one_line(skins, tmp_path):
    """Item 14: a nominal layout (no range stated: (-inf, inf)) of another head on the panel's log: the wrong-head
    error alone on stderr, no numpy "invalid value encountered in reduce" (the mid-range of (-inf, inf)) before it."""
    from metrology.core.layout import SensorLayout
    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
    from metrology.io.layout import save_layout

    t6 = layout_from_table(TABLE6_NOMINAL)
    C = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, t6.n))
    other = SensorLayout(t6.names, t6.zero + [[0.4, 0, 0], [0, 0.4, 0], [0, 0, 0.4], [0.2, 0.2, 0]], t6.direction,
                         np.full(t6.n, 0.003), np.tile([-np.inf, np.inf], (t6.n, 1)), covariance=C)
    path = tmp_path / "other.toml"
    save_layout(other, path)
    folder, files, log = skins
    out = tmp_path / "o.csv"
    r = runner.invoke(app, ["measure", log, "--layout", str(path), "--points", files["mm"][1], "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: the readings of 40 of 40 holes disagree"), r.stderr
    assert not out.exists()


def test_a_log_whose_readings_are_in_um_is_refused_in_one_line(tmp_path):
    """Issue 51: readings in µm (x1000) with a layout that states no range put the spots ~50 m out, where the 500 mm
    curvature allowance swallowed the misfit (72 % of holes "conforms"): refused naming the unit, nothing written;
    the same log in mm still measures."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pcsv

    log, um = tmp_path / "log.csv", tmp_path / "log_um.csv"
    r = runner.invoke(app, ["simulate-log", "--holes", "60", "--seed", "5", "--layout", TABLE6, "--true-layout",
                            TABLE6, "--out", str(log)])
    assert r.exit_code == 0, r.output
    t = pcsv.read_csv(log)
    pcsv.write_csv(pa.table({n: pc.multiply(t[n], 1000.0) if n.startswith("d_") else t[n] for n in t.column_names}),
                   um)
    layout = tmp_path / "no_range.toml"
    with open(TABLE6) as fh:
        layout.write_text("".join(line for line in fh if not line.startswith("range_mm")))
    out = tmp_path / "o.csv"
    for lay in (str(layout), TABLE6):
        r = runner.invoke(app, ["measure", str(um), "--layout", lay, "--out", str(out)])
        assert r.exit_code == 2, r.output
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"error: {um}: the readings put the median hole's spots"), lines
        assert "the readings look like µm: write the log's d_<sensor> columns in mm" in lines[0]
        assert not out.exists()
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert set(pcsv.read_csv(out)["status"].to_pylist()) == {"conforms"}

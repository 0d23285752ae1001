"""metro measure --dfq and calibrate --dfq: Q-DAS AQDEF files read back by an independent reader,
``aqdefreader`` (not a dependency of metro: the extras leg of .ci/run installs it with ``chardet``),
with every value, limit, time and attribute equal to metro's own tables."""

import csv
import hashlib
from datetime import datetime, timezone

import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.data import data_path
from metrology.io.layout import load_layout

aqdefreader = pytest.importorskip("aqdefreader")
pytest.importorskip("chardet")
runner = CliRunner()
M = data_path("measured")
TABLE6 = M / "nominal.toml"


def _read(path):
    from aqdefreader import read_dfq_file

    return read_dfq_file(str(path))


def _num(v) -> float:
    """aqdefreader keeps a K-field with a decimal point as its text (it parses a comma): the float of it."""
    return float(v)


def _simulate(tmp_path, holes=240, cells=2, extra=()):
    """A forward-simulated log (metro simulate-log), four holes' readings blanked: not measured."""
    log = tmp_path / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--out", str(log), "--holes", str(holes), "--cells", str(cells),
                            "--layout", str(TABLE6), "--true-layout", str(TABLE6), "--seed", "5", *extra])
    assert r.exit_code == 0, r.output
    with open(log, newline="") as fh:
        rows = list(csv.reader(fh))
    for r in rows[10:14]:
        for k, c in enumerate(rows[0]):
            if c.startswith("d_"):
                r[k] = ""
    with open(log, "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    return log


def _results(out):
    with open(out, newline="") as fh:
        return list(csv.DictReader(fh))


def _judged(row) -> float:
    after = row["angle_after_deg"]
    return float(after) if after not in ("", "nan") else float(row["angle_deg"])


def _when(row) -> datetime:
    """The hole's time in the results table (ISO 8601, UTC), to the second: K0004's resolution."""
    t = datetime.fromisoformat(row["time"])
    return t.astimezone(timezone.utc).replace(tzinfo=None, microsecond=0)


def test_measure_dfq_reads_back_equal_one_characteristic(tmp_path):
    log = _simulate(tmp_path)
    out, dfq = tmp_path / "out.csv", tmp_path / "holes.dfq"
    r = runner.invoke(app, ["measure", str(log), "--layout", str(TABLE6), "--out", str(out), "--dfq", str(dfq),
                            "--tolerance-deg", "0.4", "--json"])
    assert r.exit_code in (0, 1), r.output
    rows = _results(out)
    f = _read(dfq)
    assert f.part_count() == 1
    part = f.get_part(0)
    ch = part.get_characteristic_by_index(1)
    assert ch.get_data("K2001") == "perpendicularity" and ch.get_data("K2142") == "deg"
    assert _num(ch.get_data("K2101")) == 0.0 and _num(ch.get_data("K2111")) == 0.4
    sha = hashlib.sha256(TABLE6.read_bytes()).hexdigest()
    assert ch.get_data("K2043").endswith(f"sha256:{sha}")
    ms = ch.get_measurements()
    assert len(ms) == len(rows) == 240
    missing = 0
    for m, row in zip(ms, rows):
        assert m.datetime == _when(row)
        if row["status"] == "not_measured":
            missing += 1
            assert m.attribute == 255  # AQDEF's placeholder: not shown, not used
        else:
            assert m.attribute == 0 and _num(m.value) == _judged(row)
    assert missing == 4
    text = dfq.read_text()
    # the cell as machine (numbered; their names in K1082), the calibration's first 32 bits as gauge
    assert "K1082 cells 1 C1, 2 C2" in text
    cells = [ln.split()[1] for ln in text.splitlines() if ln.startswith("K0010/")]
    assert cells == ["1" if row["cell"] == "C1" else "2" for row in rows]
    gauges = {ln.split()[1] for ln in text.splitlines() if ln.startswith("K0012/")}
    assert gauges == {str(int(sha[:8], 16))}


def test_measure_dfq_one_characteristic_per_hole_of_the_table(tmp_path):
    from tests.measure.panel_fixtures import write_hole_table
    from metrology.sim.forward.panels import make_panel

    log = tmp_path / "flat.csv"
    r = runner.invoke(app, ["simulate-log", "--out", str(log), "--holes", "60", "--panel", "flat", "--seed", "2",
                            "--layout", str(TABLE6), "--true-layout", str(TABLE6)])
    assert r.exit_code == 0, r.output
    holes = write_hole_table(tmp_path / "flat.truth.csv", tmp_path / "holes.csv", make_panel("flat"))
    out, dfq = tmp_path / "out.csv", tmp_path / "holes.dfq"
    r = runner.invoke(app, ["measure", str(log), "--layout", str(TABLE6), "--points", str(holes), "--out", str(out),
                            "--dfq", str(dfq), "--json"])
    assert r.exit_code in (0, 1), r.output
    rows = _results(out)
    part = _read(dfq).get_part(0)
    assert part.get_data("K1001") == "holes"
    for k, row in enumerate(rows, start=1):  # each hole its own characteristic, in the table's order
        ch = part.get_characteristic_by_index(k)
        assert ch.get_data("K2001") == row["hole_id"] and _num(ch.get_data("K2111")) == 0.5
        (m,) = ch.get_measurements()
        assert _num(m.value) == _judged(row) and m.datetime == _when(row)


def test_calibrate_dfq_reads_back_the_calibrated_layout(tmp_path):
    cal, dfq = tmp_path / "cal.toml", tmp_path / "cal.dfq"
    r = runner.invoke(app, ["calibrate", str(M / "calibration.csv"), "--plane", str(M / "plane.json"), "--layout",
                            str(TABLE6), "--out", str(cal), "--dfq", str(dfq), "--json"])
    assert r.exit_code in (0, 1), r.output
    import tomllib

    stated = tomllib.loads(cal.read_text())["sensors"]  # the values as the calibration file states them
    nominal = load_layout(TABLE6)
    part = _read(dfq).get_part(0)
    sha = hashlib.sha256(cal.read_bytes()).hexdigest()
    k = 0
    for j, s in enumerate(stated):
        name = s["name"]
        for what, axes, cal_v, nom_v in (("zero", "xyz", s["zero"], nominal.zero[j]),
                                         ("direction", "ijk", s["direction"], nominal.direction[j])):
            for a, v, nv in zip(axes, cal_v, nom_v):
                k += 1
                ch = part.get_characteristic_by_index(k)
                assert ch.get_data("K2001") == f"{name}.{what}_{a}"
                assert _num(ch.get_data("K2101")) == nv
                assert ch.get_data("K2043").endswith(f"sha256:{sha}")
                (m,) = ch.get_measurements()
                assert _num(m.value) == v and m.attribute == 0
    assert k == 6 * len(stated)


def test_bad_dfq_path_exits_2_and_a_failed_run_leaves_no_file(tmp_path):
    log = _simulate(tmp_path, holes=40, cells=1)
    r = runner.invoke(app, ["measure", str(log), "--layout", str(TABLE6), "--dfq", str(tmp_path / "x.txt")])
    assert r.exit_code == 2 and "--dfq" in r.output and ".dfq" in r.output
    bad = tmp_path / "bad.csv"
    lines = log.read_text().splitlines()
    lines[20] = lines[20].replace(",", ",x", 6)  # a reading that is not a number, mid-log
    bad.write_text("\n".join(lines) + "\n")
    dfq = tmp_path / "bad.dfq"
    r = runner.invoke(app, ["measure", str(bad), "--layout", str(TABLE6), "--dfq", str(dfq), "--json"])
    assert r.exit_code == 2, r.output
    assert not dfq.exists() and not list(tmp_path.glob(".bad.dfq*"))

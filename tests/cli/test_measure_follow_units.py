"""metro measure --follow holds its first lines to the units checks the batch run holds a log to (issue 51): the
readings' unit (the reach rule, jobs/measure.py) and the commanded positions' (io/panel_units.py), on its first
:data:`metrology.jobs.measure_follow.UNIT_LINES` lines: refused in one line, exit 2, the batch run's message, before
any hole is answered."""

import csv
import io
import json

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pcsv
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.jobs.measure_follow import UNIT_LINES
from tests.cli.test_measure_units import TABLE6, _log_in, skins  # noqa: F401 - skins: the module's fixture

runner = CliRunner()


def _first(log, tmp_path, name, lines=UNIT_LINES):
    """The header and the first ``lines`` holes of ``log``, as a file."""
    out = tmp_path / name
    with open(log, encoding="utf-8") as fh:
        out.write_text("".join(fh.readlines()[:lines + 1]), encoding="utf-8")
    return out


def _both(log, *args):
    """The batch run and the followed run (stdin, and the file followed) of ``log``."""
    batch = runner.invoke(app, ["measure", str(log), "--layout", TABLE6, *args])
    live = runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow", *args],
                         input=open(log, encoding="utf-8").read())
    filed = runner.invoke(app, ["measure", str(log), "--layout", TABLE6, "--follow", *args])
    return batch, live, filed


def _refused(r, start):
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {start}"), r.stderr
    assert r.stdout == ""  # no hole answered, no summary
    return lines[0]


def test_readings_in_um_are_refused_on_the_first_lines_as_the_batch_run_refuses_them(tmp_path):
    log = tmp_path / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--holes", "30", "--seed", "5", "--layout", TABLE6, "--true-layout",
                            TABLE6, "--out", str(log)])
    assert r.exit_code == 0, r.output
    t = pcsv.read_csv(log)
    um = tmp_path / "log_um.csv"
    pcsv.write_csv(pa.table({n: pc.multiply(t[n], 1000.0) if n.startswith("d_") else t[n] for n in t.column_names}),
                   um)
    first = _first(um, tmp_path, "first_um.csv")
    batch, live, filed = _both(first)
    words = "the readings look like µm: write the log's d_<sensor> columns in mm"
    line = _refused(batch, f"{first}: the readings put the median hole's spots")
    assert words in line
    assert _refused(filed, f"{first}: ") == line  # the batch run's message, word for word
    assert _refused(live, "<stdin>: ") == line.replace(str(first), "<stdin>")
    # the whole log, followed: refused on its first lines too
    _refused(runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow"], input=um.read_text()), "<stdin>: ")
    # the same lines in mm are answered
    r = runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow"], input=log.read_text())
    assert r.exit_code in (0, 1), r.output
    assert sum('"hole_id"' in x for x in r.stdout.splitlines()) == 30


def test_positions_in_inches_against_a_mm_panel_and_table_are_refused_on_the_first_lines(skins, tmp_path):  # noqa: F811
    folder, files, log = skins
    bad = _log_in(log, folder, "in", 25.4)
    first = _first(bad, tmp_path, "first_in.csv")
    panel = ["--panel", files["mm"][0], "--points", files["mm"][1]]
    batch, live, filed = _both(first, *panel)
    line = _refused(batch, f"{first}: the log's commanded positions lie a median")
    assert "(pose_x_mm, pose_y_mm, pose_z_mm) look like inches: write them in mm" in line
    assert _refused(filed, f"{first}: ") == line
    assert _refused(live, "<stdin>: ") == line.replace(str(first), "<stdin>")
    # the table alone (no panel): the same check
    r = runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow", "--points", files["mm"][1]],
                      input=open(bad, encoding="utf-8").read())
    assert "look like inches: write them in mm" in _refused(r, "<stdin>: the log's commanded positions")
    # the log in mm: answered
    r = runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow", *panel], input=open(log).read())
    assert r.exit_code in (0, 1), r.output
    assert sum('"hole_id"' in x for x in r.stdout.splitlines()) == 40


@pytest.mark.parametrize("holes", [1, UNIT_LINES - 1])
def test_a_stream_shorter_than_the_checked_lines_is_checked_at_its_end(skins, tmp_path, holes):  # noqa: F811
    """Fewer lines than the checks hold: checked when the stream ends (the positions' rule takes any number of holes;
    the reach rule needs UNIT_LINES, as in a batch run of as few holes)."""
    folder, files, log = skins
    bad = _first(_log_in(log, folder, "in", 25.4), tmp_path, f"short{holes}.csv", holes)
    r = runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow", "--points", files["mm"][1]],
                      input=bad.read_text())
    assert "look like inches" in _refused(r, "<stdin>: the log's commanded positions")


def test_one_gross_reading_among_the_first_lines_does_not_refuse_the_run(tmp_path):
    """The reach rule takes the median hole of the first lines: one reading off by 10 m (a sensor's no-reading code)
    on the first line is that hole's problem, not the log's unit."""
    log = tmp_path / "log.csv"
    r = runner.invoke(app, ["simulate-log", "--holes", "8", "--seed", "6", "--layout", TABLE6, "--true-layout",
                            TABLE6, "--out", str(log), "--no-truth"])
    assert r.exit_code == 0, r.output
    with open(log, newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    rows[1][rows[0].index("d_L1")] = "9999.0"
    text = io.StringIO()
    csv.writer(text, lineterminator="\n").writerows(rows)
    r = runner.invoke(app, ["measure", "-", "--layout", TABLE6, "--follow"], input=text.getvalue())
    assert r.exit_code in (0, 1), r.output
    holes = [json.loads(x) for x in r.stdout.splitlines() if '"hole_id"' in x]
    assert len(holes) == 8 and "L1 = 9999" in holes[0]["reason"], holes[0]  # that sensor left out, named

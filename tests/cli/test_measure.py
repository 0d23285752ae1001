"""metro measure from the command line: exit codes by verdict, JSON, stdout, stdin, resume, report."""

import json

import numpy as np

import pyarrow as pa
import pyarrow.compute  # noqa: F401  (pa.compute below)
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.layout import save_layout
from tests.measure.helpers import calibrated_layout, hole_log, write_log_csv

runner = CliRunner()


@pytest.fixture
def layout(tmp_path):
    p = tmp_path / "calibrated.toml"
    save_layout(calibrated_layout(), p)
    return p


def _log(tmp_path, name="log.csv", **kw):
    cols, _, _ = hole_log(calibrated_layout(), **kw)
    return write_log_csv(cols, tmp_path / name)


def test_all_conform_exits_0_with_a_passed_verdict(tmp_path, layout):
    log = _log(tmp_path, n=300, angle_deg=(1, 4), after_deg=(0.0, 0.1))
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.parquet"),
                            "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    assert s["schema"] == "metro.measure/1"
    assert s["verdict"]["passed"] is True
    assert s["counts"] == {"conforms": 300, "fails": 0, "undecided": 0, "not_measured": 0}
    assert s["judged"] == {"after_adjustment": 300, "before_adjustment": 0}
    assert {c["name"] for c in s["verdict"]["checks"]} >= {"drilling tolerance: holes that fail"}
    t = pq.read_table(tmp_path / "h.parquet")
    assert t.column_names[:13] == ["hole_id", "normal_x", "normal_y", "normal_z", "angle_deg", "U95_angle_deg",
                                   "angle_after_deg", "U95_after_deg", "fit_residual_um", "fit_residual_after_um",
                                   "sensors_used", "status", "reason"]
    assert t.num_rows == 300


def test_a_failing_hole_exits_1(tmp_path, layout):
    log = _log(tmp_path, n=100, angle_deg=(1, 4))  # no after-readings: judged as measured
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.csv"), "--json"])
    assert r.exit_code == 1, r.output
    s = json.loads(r.stdout)
    assert s["verdict"]["passed"] is False and s["counts"]["fails"] == 100


def test_csv_to_stdout_and_the_summary_to_stderr(tmp_path, layout):
    log = _log(tmp_path, n=20, angle_deg=(0.01, 0.1))
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout)])
    assert r.exit_code == 0, r.output
    lines = r.stdout.strip().splitlines()
    assert lines[0].startswith('"hole_id","normal_x"') and len(lines) == 21
    assert "verdict: passed (exit code 0)" in r.stderr


def test_stdin(tmp_path, layout):
    log = _log(tmp_path, n=20, angle_deg=(0.01, 0.1))
    r = runner.invoke(app, ["measure", "-", "--layout", str(layout), "--out", str(tmp_path / "h.csv"), "--json"],
                      input=log.read_bytes())
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["sources"]["log"] == "<stdin>"


@pytest.mark.parametrize("mutate, message", [
    (lambda c: c["time"].__setitem__(5, "2026-11-25T07:00:00Z"), r"log\.csv line 7: time 2026-11-25T07:00:00Z is before the previous hole of cell 'C1' \(line 6"),
    (lambda c: c["d_L2"].__setitem__(3, "abc"), r"line 5: d_L2 = 'abc' is not a number"),
])
def test_bad_input_exits_2_with_one_line_and_no_output(tmp_path, layout, mutate, message):
    import re

    cols, _, _ = hole_log(calibrated_layout(), n=10)
    cols = {k: list(map(str, v)) if k.startswith("d_") else v for k, v in cols.items()}
    mutate(cols)
    log = write_log_csv(cols, tmp_path / "log.csv")
    out = tmp_path / "h.csv"
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(out)])
    assert r.exit_code == 2
    assert re.search(message, r.stderr), r.stderr
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert not out.exists()


def test_layout_without_covariance_warns(tmp_path):
    from dataclasses import replace

    p = tmp_path / "nominal.toml"
    save_layout(replace(calibrated_layout(), covariance=None), p)
    log = _log(tmp_path, n=10, angle_deg=(0.01, 0.1))
    r = runner.invoke(app, ["measure", str(log), "--layout", str(p), "--out", str(tmp_path / "h.csv")])
    assert r.exit_code == 0
    assert "no [calibration] covariance: U95 carries the reading noise only" in r.stderr


def test_partitioned_log_resumes_without_duplicating(tmp_path, layout):
    root = tmp_path / "fleet"
    cols, _, _ = hole_log(calibrated_layout(), n=60, cells=("C1", "C2"), angle_deg=(0.01, 0.1))
    t = pa.table(cols)
    for cell in ("C1", "C2"):
        part = t.filter(pa.compute.equal(t.column("cell"), cell)).drop_columns(["cell"])
        (root / f"cell={cell}").mkdir(parents=True)
        pq.write_table(part, root / f"cell={cell}" / "part-0.parquet")
    out = tmp_path / "out"
    args = ["measure", str(root), "--layout", str(layout), "--out", str(out), "--json"]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    (out / "cell=C2" / "part-0.parquet").unlink()  # as if killed before the second partition
    kept = (out / "cell=C1" / "part-0.parquet").stat().st_mtime_ns
    second = runner.invoke(app, args)
    assert second.exit_code == 0
    s = json.loads(second.stdout)
    assert s["partitions_written"] == 1 and s["holes"] == 120
    assert (out / "cell=C1" / "part-0.parquet").stat().st_mtime_ns == kept
    ds = pq.read_table(out, partitioning="hive")
    assert ds.num_rows == 120 and sorted(set(ds.column("cell").to_pylist())) == ["C1", "C2"]
    other = runner.invoke(app, [*args[:-1], "--tolerance-deg", "0.3"])
    assert other.exit_code == 2 and "other settings" in other.stderr


def test_report_is_written_and_named(tmp_path, layout):
    log = _log(tmp_path, n=1300, angle_deg=(1, 4), after_deg=(0.0, 0.1), shift=(2, 1150, 0.03))
    rep = tmp_path / "r.html"
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.csv"),
                            "--report", str(rep), "--json", "--fail-on-drift"])
    assert r.exit_code == 1, r.output  # the knocked L3 raised an alarm, and --fail-on-drift fails on it
    s = json.loads(r.stdout)
    assert len(s["drift"]["alarms"]) == 1 and s["counts"]["fails"] == 0
    a = s["drift"]["alarms"][0]
    assert a["advice"] == "recalibrate" and abs(a["sensor_shift_um"]["L3"] - 30) < 5
    html = rep.read_text()
    assert "Hole measurement" in html and "recalibrate" in html.lower()
    assert f"report: {rep}" in r.stderr


def test_a_transient_knock_is_shown_but_does_not_fail_the_drift_gate(tmp_path, layout):
    """L3 knocked by 30 um for 40 holes, then back: the chart alarms on the run, the level after it is
    the old one. The alarm is named as not persisted ("check the head") and --fail-on-drift does not
    fail on it (it gates a change that persisted: a recalibration); the verdict lists it."""
    cols, _, _ = hole_log(calibrated_layout(), n=2400, angle_deg=(1, 4), after_deg=(0.0, 0.1))
    for key in ("d_L3", "d_L3_after"):
        cols[key] = [v + 0.03 if 1150 <= i < 1190 else v for i, v in enumerate(cols[key])]
    log = write_log_csv(cols, tmp_path / "log.csv")
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.csv"),
                            "--json", "--fail-on-drift"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)
    alarms = s["drift"]["alarms"]
    assert len(alarms) == 1 and alarms[0]["persisted"] is False and alarms[0]["advice"].startswith("check the head")
    assert 1150 <= int(alarms[0]["hole_id"].rsplit("-", 1)[1]) < 1190
    checks = {c["name"]: c for c in s["verdict"]["checks"]}
    assert checks["drift watch: alarms whose run did not persist (check the head)"]["value"] == 1
    assert checks["drift watch: alarms whose change persisted (recalibrate)"]["value"] == 0
    # the text says it once (issue 51, item 14: "the run did not persist: check the head: the run did not persist")
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h2.csv")])
    assert r.output.count("did not persist (a false alarm") == 1 and "persist: check the head: the run" not in r.output


def test_nothing_judged_says_so_not_nan(tmp_path, layout):
    """Issue 51, item 14: "judged angle: mean nan deg, s nan deg" when no hole was judged."""
    cols, _, _ = hole_log(calibrated_layout(), n=30, angle_deg=(1, 2))
    for s in ("L1", "L2"):
        cols[f"d_{s}"] = [None] * 30  # 2 readings a hole: none measured
    log = write_log_csv(cols, tmp_path / "log.csv")
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.csv")])
    assert "judged angle: none (no hole was judged)" in r.output and " nan " not in r.output


def test_a_layout_that_does_not_fit_the_head_is_refused(tmp_path):
    """Readings that disagree with one plane at most holes: another head's layout, exit 2, no file."""
    lay = calibrated_layout()
    other = lay.with_params(lay.zero + [[0.4, 0, 0], [0, 0.4, 0], [0, 0, 0.4], [0.2, 0.2, 0]], lay.direction)
    p = tmp_path / "other.toml"
    save_layout(other, p)
    log = _log(tmp_path, n=100, angle_deg=(0.5, 2))
    out = tmp_path / "h.csv"
    r = runner.invoke(app, ["measure", str(log), "--layout", str(p), "--out", str(out), "--min-radius-mm", "inf"])
    assert r.exit_code == 2
    assert "the readings of 100 of 100 holes disagree with one plane" in r.stderr
    assert not out.exists()


@pytest.mark.parametrize("kind", ["csv", "parquet"])
@pytest.mark.parametrize("extra", [[], ["--out", "h.csv"], ["--out", "h.parquet", "--report", "r.html"], ["--json", "--out", "h.csv"]])
def test_a_log_without_rows_is_one_line_naming_the_log(tmp_path, layout, kind, extra):
    header = ["hole_id", "time", "d_L1", "d_L2", "d_L3", "d_L4"]
    if kind == "csv":
        log = tmp_path / "empty.csv"
        log.write_text(",".join(header) + "\n")
    else:
        log = tmp_path / "empty.parquet"
        pq.write_table(pa.table({c: pa.array([], pa.string() if c in ("hole_id", "time") else pa.float64())
                                 for c in header}), log)
    extra = [str(tmp_path / a) if a.endswith((".csv", ".parquet", ".html")) else a for a in extra]
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), *extra])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(log) in lines[0] and "no rows" in lines[0], r.stderr
    assert "Traceback" not in r.output and not any(p.name.startswith(("h.", "r.")) for p in tmp_path.iterdir())


def test_a_layout_that_is_not_text_names_the_file(tmp_path):
    from pathlib import Path

    log = _log(tmp_path, n=30)
    ply = Path(__file__).resolve().parents[2] / "metrology" / "data" / "measured" / "datum.ply"
    r = runner.invoke(app, ["measure", str(log), "--layout", str(ply), "--out", str(tmp_path / "h.csv")])
    assert r.exit_code == 2, r.output
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and str(ply) in lines[0] and "TOML" in lines[0] and "codec" not in lines[0], r.stderr


def test_a_closed_pipe_is_quiet(tmp_path, layout):
    """`metro measure log.csv --layout L | head -1`: the reader went away; not bad input."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    log = _log(tmp_path, n=3000)
    root = Path(__file__).resolve().parents[2]
    p = subprocess.Popen([sys.executable, "-m", "cli.main", "-q", "measure", str(log), "--layout", str(layout)],
                         cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, "COLUMNS": "200"})
    first = p.stdout.readline()
    p.stdout.close()  # as head -1 does
    err = p.stderr.read().decode()
    code = p.wait(timeout=120)
    assert first.startswith(b"\"hole_id\"")
    assert "error" not in err and "Broken pipe" not in err and "Traceback" not in err, err
    assert code == 128 + 13  # as a process killed by SIGPIPE, what a shell shows for a closed pipe


def test_a_run_killed_mid_write_leaves_nothing_the_next_run_keeps(tmp_path, layout):
    """`kill -9` while --out k.parquet is being written leaves its temporary; the next run clears it."""
    import subprocess
    import sys
    from pathlib import Path

    log = _log(tmp_path, n=200)
    out = tmp_path / "k.parquet"
    root = Path(__file__).resolve().parents[2]
    killed = subprocess.run([sys.executable, "-c", (
        "import os, signal, pyarrow as pa\n"
        "from metrology.io.holeout import TableSink\n"
        f"s = TableSink({str(out)!r}).__enter__()\n"
        "s.write(pa.table({'a': list(range(1000))}))\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n")], cwd=root)
    assert killed.returncode == -9
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".k.parquet.")]  # the temporary it left
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(out)])
    assert r.exit_code in (0, 1), r.output
    assert out.exists() and not [p.name for p in tmp_path.iterdir() if p.name.startswith(".k.parquet.")]


@pytest.mark.parametrize("times", ["iso", "seconds"])
def test_time_from_a_csv_log_is_written_as_a_timestamp(tmp_path, layout, times):
    import datetime as dt

    import pyarrow.csv as pcsv

    cols, _, _ = hole_log(calibrated_layout(), n=20)
    t0 = 1795586401.25
    cols["time"] = [(dt.datetime.fromtimestamp(t0 + 60 * i, dt.timezone.utc).isoformat() if times == "iso"
                     else f"{t0 + 60 * i:.3f}") for i in range(20)]
    log = write_log_csv(cols, tmp_path / "log.csv")
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.parquet")])
    assert r.exit_code in (0, 1), r.output
    t = pq.read_table(tmp_path / "h.parquet").column("time")
    assert pa.types.is_timestamp(t.type) and t.type.tz == "UTC"
    got = t.cast(pa.int64()).to_numpy() / {"s": 1, "ms": 1e3, "us": 1e6, "ns": 1e9}[t.type.unit]
    assert got == pytest.approx(t0 + 60 * np.arange(20), abs=1e-6)
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--out", str(tmp_path / "h.csv")])
    back = pcsv.read_csv(tmp_path / "h.csv").column("time")
    assert pa.types.is_timestamp(back.type)  # written as a timestamp, read back as one (not quoted text)
    assert '"2026-' not in (tmp_path / "h.csv").read_text()


def test_json_without_out_prints_the_summary_only(tmp_path, layout):
    log = _log(tmp_path, n=50, angle_deg=(1, 4), after_deg=(0.0, 0.1))
    r = runner.invoke(app, ["measure", str(log), "--layout", str(layout), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.stdout)  # the summary alone: no per-hole CSV mixed in
    assert s["holes"] == 50 and s["sources"]["out"] is None
    assert not [p for p in tmp_path.iterdir() if p.suffix in (".csv", ".parquet") and p != log]


def _two_cell_fleet(root):
    """A 60-hole log of cells C1 and C2 as a hive folder ``root`` (``cell=C1/part-0.parquet``, ...); its table."""
    cols, _, _ = hole_log(calibrated_layout(), n=60, cells=("C1", "C2"), angle_deg=(0.01, 0.1))
    t = pa.table(cols)
    for cell in ("C1", "C2"):
        (root / f"cell={cell}").mkdir(parents=True)
        pq.write_table(t.filter(pa.compute.equal(t.column("cell"), cell)).drop_columns(["cell"]),
                       root / f"cell={cell}" / "part-0.parquet")
    return t


def test_a_resumed_run_says_how_many_partitions_it_kept(tmp_path, layout):
    root = tmp_path / "fleet"
    _two_cell_fleet(root)
    out = tmp_path / "out"
    args = ["measure", str(root), "--layout", str(layout), "--out", str(out)]
    assert runner.invoke(app, args).exit_code == 0
    (out / "cell=C2" / "part-0.parquet").unlink()
    r = runner.invoke(app, args)
    assert "resumed: 1 of 2 partition(s) kept as an earlier run wrote them, 1 written" in r.output, r.output


def test_a_first_run_into_one_file_says_it_wrote_it_not_that_it_resumed(tmp_path, layout):
    """A one-file output (CSV, Parquet) is written whole by the run: no "resumed" line, and --json's
    ``partitions_written`` counts it (it once said 0 and "kept as an earlier run wrote them")."""
    root = tmp_path / "fleet"
    t = _two_cell_fleet(root)
    log = tmp_path / "log.parquet"
    pq.write_table(t, log)
    for src, out in ((log, tmp_path / "holes.csv"), (log, tmp_path / "holes.parquet"), (root, tmp_path / "all.parquet")):
        r = runner.invoke(app, ["measure", str(src), "--layout", str(layout), "--out", str(out)])
        assert r.exit_code == 0 and out.exists(), r.output
        assert "resumed" not in r.output and "already written" not in r.output, r.output
        j = runner.invoke(app, ["measure", str(src), "--layout", str(layout), "--out", str(out), "--json"])
        s = json.loads(j.stdout)
        assert s["partitions_written"] == s["partitions"], s


def test_report_histogram_axis_ends_near_the_largest_angle_and_versions_name_pyarrow_dask(tmp_path, layout):
    import matplotlib

    matplotlib.use("Agg")
    from metrology.jobs.measure import MeasureOptions, measure_files
    from metrology.report.measure import _hist_figure

    log = _log(tmp_path, n=300, angle_deg=(1, 4), after_deg=(0.0, 0.1))
    rep = measure_files(log, layout, MeasureOptions(out=tmp_path / "h.csv", report_html=tmp_path / "r.html"))
    hi = _hist_figure(rep).axes[0].get_xlim()[1]
    assert 4 <= hi <= 12, hi  # the largest angle is 4 deg: not 100
    html = (tmp_path / "r.html").read_text()
    assert "pyarrow" in html and "dask" in html

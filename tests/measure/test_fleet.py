"""The Dask path (metro[fleet]): the same per-hole results, summary and alarms as one process, on a
LocalCluster and on a real `dask scheduler` with two `dask worker` processes on localhost."""

import json
import re
import os
import shutil
import socket
import subprocess
import sys
import time

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from cli.main import app
from metrology.io.layout import save_layout

from .helpers import calibrated_layout, hole_log

distributed = pytest.importorskip("distributed")
runner = CliRunner()


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """A partitioned log of 3 cells x 2 days, one cell with a knocked L2, and the layout."""
    root = tmp_path_factory.mktemp("fleet")
    lay = calibrated_layout()
    save_layout(lay, root / "calibrated.toml")
    for k, cell in enumerate(("C1", "C2", "C3")):
        cols, _, _ = hole_log(lay, n=1400, seed=k, cells=(cell,), angle_deg=(1, 4), after_deg=(0.0, 0.3),
                              shift=(1, 1200, 0.03) if cell == "C2" else None)
        t = pa.table(cols).drop_columns(["cell"])
        for day, rows in (("2026-11-25", slice(0, 700)), ("2026-11-26", slice(700, 1400))):
            d = root / "log" / f"cell={cell}" / f"date={day}"
            d.mkdir(parents=True)
            pq.write_table(t.slice(rows.start, rows.stop - rows.start), d / "part-0.parquet")
    return root


def _finished(r):
    """A CLI run that ended with a verdict (exit 0 or 1), not with a crash (CliRunner gives an
    uncaught exception exit code 1 too: its ``exception`` tells them apart)."""
    assert r.exit_code in (0, 1) and isinstance(r.exception, (SystemExit, type(None))), (r.output, repr(r.exception))


def _run(fleet, out, *extra):
    r = runner.invoke(app, ["measure", str(fleet / "log"), "--layout", str(fleet / "calibrated.toml"),
                            "--out", str(out), "--json", *extra])
    _finished(r)
    s = json.loads(r.stdout)
    s.pop("engine")
    s["sources"].pop("out")
    return s


def _run_relative(fleet, out, *extra):
    """As :func:`_run`, from ``fleet``'s folder with every path relative."""
    r = runner.invoke(app, ["measure", "log", "--layout", "calibrated.toml", "--out", out, "--json", *extra])
    _finished(r)
    s = json.loads(r.stdout)
    s.pop("engine")
    s["sources"].pop("out")
    s["sources"]["log"] = str(fleet / "log")
    s["sources"]["layout"] = str(fleet / "calibrated.toml")
    return s


def _same_files(a, b):
    fa = sorted(p.relative_to(a) for p in a.rglob("*.parquet"))
    assert fa == sorted(p.relative_to(b) for p in b.rglob("*.parquet")) and len(fa) == 6
    for rel in fa:
        assert pq.read_table(a / rel).equals(pq.read_table(b / rel)), rel


def test_local_cluster_gives_the_single_process_results(fleet, tmp_path):
    one = _run(fleet, tmp_path / "one")
    two = _run(fleet, tmp_path / "dask", "--workers", "2")
    assert one == two
    assert [a["cell"] for a in one["drift"]["alarms"]] == ["C2"]
    _same_files(tmp_path / "one", tmp_path / "dask")


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_real_scheduler_and_two_workers(fleet, tmp_path):
    dask = shutil.which("dask", path=os.path.dirname(sys.executable)) or shutil.which("dask")
    if dask is None:
        pytest.fail("the dask command is missing though distributed imports")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    cwd = os.getcwd()
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)]
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
                break
            except OSError:
                time.sleep(0.2)
        for _ in range(2):
            procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1", "--nthreads", "1",
                                           "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          env=env, cwd=elsewhere))
        from distributed import Client

        with Client(address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
            assert len(c.scheduler_info()["workers"]) == 2
        # paths given relative to the client's folder, workers started in another: resolved before they go
        os.chdir(fleet)
        two = _run_relative(fleet, "cluster", "--scheduler", address)
        one = _run(fleet, tmp_path / "one")
        assert one == two
        _same_files(tmp_path / "one", fleet / "cluster")
    finally:
        os.chdir(cwd)
        shutil.rmtree(fleet / "cluster", ignore_errors=True)
        for p in procs[::-1]:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_one_parquet_file_on_dask_into_one_file_with_its_qif(fleet, tmp_path):
    """A single Parquet log on --workers: its row groups are the tasks, the results one file (and one
    QIF document), the same as one process's, byte for byte."""
    log = tmp_path / "log.parquet"
    parts = sorted((fleet / "log").rglob("*.parquet"))
    with pq.ParquetWriter(log, pq.read_table(parts[0]).append_column("cell", pa.array([""] * 700)).schema) as w:
        for p in parts:  # one row group per partition: 6 tasks
            w.write_table(pq.read_table(p).append_column("cell", pa.array([p.parent.parent.name[5:]] * 700)))
    assert pq.ParquetFile(log).num_row_groups == 6
    out = {}
    for name, extra in (("one", []), ("dask", ["--workers", "2"])):
        r = runner.invoke(app, ["measure", str(log), "--layout", str(fleet / "calibrated.toml"), "--out",
                                str(tmp_path / f"{name}.parquet"), "--qif", str(tmp_path / f"{name}.qif"), "--json",
                                *extra])
        _finished(r)
        out[name] = json.loads(r.stdout)
    for k in ("counts", "fleet", "cells", "groups", "drift", "worst", "holes"):
        assert out["one"][k] == out["dask"][k], k
    assert out["dask"]["partitions"] == 6 and out["dask"]["holes"] == 4200
    assert [a["cell"] for a in out["one"]["drift"]["alarms"]] == ["C2"]
    assert pq.read_table(tmp_path / "one.parquet").equals(pq.read_table(tmp_path / "dask.parquet"))
    assert (tmp_path / "one.qif").read_bytes() == (tmp_path / "dask.qif").read_bytes()


def test_a_scheduler_that_cannot_be_reached_leaves_nothing(fleet, tmp_path, monkeypatch):
    monkeypatch.setattr("metrology.measure.fleet.CONNECT_TIMEOUT_S", 1)  # Dask retries until then
    r = runner.invoke(app, ["measure", str(fleet / "log"), "--layout", str(fleet / "calibrated.toml"), "--out",
                            str(tmp_path / "out"), "--scheduler", f"tcp://127.0.0.1:{_free_port()}"])
    assert r.exit_code == 2, r.output
    assert "cannot reach the Dask scheduler" in r.output
    assert not (tmp_path / "out").exists()


def test_time_out_of_order_across_a_cells_partitions_is_the_same_error_on_dask(fleet, tmp_path):
    """The drift watch's chain on the workers checks each cell's time order across partitions as
    one process does: the same one-line error, exit 2."""
    log = tmp_path / "log"
    shutil.copytree(fleet / "log", log)
    late = log / "cell=C3" / "date=2026-11-25" / "part-0.parquet"  # C3's first day now after its second
    t = pq.read_table(late)
    t = t.set_column(t.column_names.index("time"), "time",
                     pa.array([v.replace("2026-11-25", "2026-11-27") for v in t.column("time").to_pylist()]))
    pq.write_table(t, late)
    lines = []
    for name, extra in (("one", []), ("dask", ["--workers", "2"])):
        r = runner.invoke(app, ["measure", str(log), "--layout", str(fleet / "calibrated.toml"), "--out",
                                str(tmp_path / name), *extra])
        assert r.exit_code == 2, r.output
        lines.append([ln for ln in r.stderr.splitlines() if "is before the previous hole of cell 'C3'" in ln])
    assert len(lines[0]) == 1 and lines[0] == lines[1], lines


def test_a_cluster_that_loses_the_run_is_a_one_line_error(fleet, tmp_path):
    """A task whose workers keep dying (KilledWorker) or a scheduler gone (cancelled futures): a
    ValueError (one line at the CLI, exit 2), not a traceback."""
    from distributed import KilledWorker

    from metrology.io.holelog import open_log
    from metrology.io.layout import load_layout
    from metrology.measure.fleet import DaskEngine
    from metrology.measure.run import measure_log
    from metrology.measure.holes import Settings
    from concurrent.futures import CancelledError

    lay = load_layout(fleet / "calibrated.toml")
    log = open_log(fleet / "log", lay.names)

    class Killed(KilledWorker):  # its constructor's arguments vary across distributed's versions
        def __init__(self):
            Exception.__init__(self, "metro-measure-0")

        def __str__(self):
            return "metro-measure-0 killed 3 workers"

    for exc in (Killed(), CancelledError("metro-measure-0")):
        class Future:
            def result(self):
                raise exc

            def release(self):
                pass

        class Client:
            def nthreads(self):
                return {"tcp://127.0.0.1:1": 1}

            def submit(self, *args, **kwargs):
                return Future()

            def gather(self, futures):
                raise exc

        with pytest.raises(ValueError, match=r"the Dask cluster stopped the run \((Killed|CancelledError): .*a re-run "
                                             r"with the same --out resumes"):
            measure_log(log, lay, Settings(), DaskEngine(Client()))


class _KillOnce(distributed.WorkerPlugin):
    """A worker plugin that kills its worker's process (SIGKILL), once (a marker file says it has),
    in the task of partition 1: ``mid``, as soon as the partition's temporary file is there (its
    results half written); ``after``, as the task has ended (its file written, its result not yet
    with the client)."""

    def __init__(self, marker, folder, when):
        self.marker, self.folder, self.when = str(marker), str(folder), when

    def transition(self, key, start, finish, **kwargs):
        import signal
        import threading

        if not str(key).startswith("metro-measure-1-") or os.path.exists(self.marker):
            return
        if self.when == "after" and finish == "memory":
            open(self.marker, "w").close()
            os.kill(os.getpid(), signal.SIGKILL)
        if self.when == "mid" and finish == "executing":
            def kill_when_half_written():
                while not any(n.startswith(".part-0.parquet.") for n in os.listdir(self.folder)):
                    time.sleep(0.001)
                open(self.marker, "w").close()
                os.kill(os.getpid(), signal.SIGKILL)

            os.makedirs(self.folder, exist_ok=True)
            threading.Thread(target=kill_when_half_written, daemon=True).start()


@pytest.mark.parametrize("when", ["mid", "after"])
def test_a_worker_killed_in_a_partition_is_re_run_and_the_results_are_the_same(fleet, tmp_path, when):
    """A real LocalCluster worker process killed while it writes a partition, or after it wrote
    it: Dask re-runs the partition on a new worker; every partition's file is written once, whole,
    the same as one process's (no hole missing or twice), no temporary is left, and a file the lost
    worker wrote counts as this run's."""
    import cloudpickle

    from metrology.io.holelog import open_log
    from metrology.io.holeout import PartitionedOutput
    from metrology.io.layout import load_layout
    from metrology.measure.fleet import DaskEngine, connect
    from metrology.measure.holes import Settings
    from metrology.measure.run import measure_log

    lay = load_layout(fleet / "calibrated.toml")
    log = open_log(fleet / "log", lay.names, batch_rows=100)  # 7 batches a partition: killed between them
    assert log.partitions[1].relative == "cell=C1/date=2026-11-26/part-0.parquet"
    one = measure_log(log, lay, Settings(), output=PartitionedOutput(tmp_path / "one", {}))
    marker = tmp_path / "killed"
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    try:
        with connect(workers=2) as client:
            client.register_plugin(_KillOnce(marker, tmp_path / "dask" / "cell=C1" / "date=2026-11-26", when))
            out = PartitionedOutput(tmp_path / "dask", {})
            two = measure_log(log, lay, Settings(), DaskEngine(client), output=out)
            out.release()
    finally:
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert marker.exists()  # the worker was killed
    assert two.rows == one.rows == 4200 and two.written == 6
    assert two.summary.counts() == one.summary.counts()
    assert [a.to_dict() for a in two.alarms] == [a.to_dict() for a in one.alarms]
    _same_files(tmp_path / "one", tmp_path / "dask")
    assert not [p for p in (tmp_path / "dask").rglob(".*") if p.is_file()]  # no temporary left


def test_a_partition_that_disagrees_with_its_cell_key_is_the_same_error_on_dask(fleet, tmp_path):
    log = tmp_path / "log"
    shutil.copytree(fleet / "log", log)
    bad = log / "cell=C2" / "date=2026-11-26" / "part-0.parquet"
    t = pq.read_table(bad)
    pq.write_table(t.append_column("cell", pa.array(["C9"] * t.num_rows)), bad)
    lines = []
    for name, extra in (("one", []), ("dask", ["--workers", "2"])):
        r = runner.invoke(app, ["measure", str(log), "--layout", str(fleet / "calibrated.toml"), "--out",
                                str(tmp_path / name), *extra])
        assert r.exit_code == 2, r.output
        lines.append([ln for ln in r.stderr.splitlines() if "disagrees with its folder's cell=C2" in ln])
        assert "Traceback" not in r.output
    assert len(lines[0]) == 1 and lines[0] == lines[1], lines
    assert not list((tmp_path / "dask").rglob("cell=C2/date=2026-11-26/*"))  # that partition: no file, no temporary


def test_two_runs_into_one_folder_at_once_the_second_is_refused(fleet, tmp_path, monkeypatch):
    """A live run's lock: the second run waits LOCK_WAIT_S, then a one-line error, exit 2; a lock
    left by a killed run (its process gone) is taken over."""
    import metrology.io.holeout as holeout

    monkeypatch.setattr(holeout, "LOCK_WAIT_S", 0.5)
    out = tmp_path / "out"
    out.mkdir()
    lock = out / holeout.LOCK
    lock.write_text(f"pid {os.getpid()} on {socket.gethostname()}")  # this process: alive
    args = ["measure", str(fleet / "log"), "--layout", str(fleet / "calibrated.toml"), "--out", str(out)]
    r = runner.invoke(app, args)
    assert r.exit_code == 2, r.output
    assert "another run is writing into it" in r.output and "waited 0.5 s" in r.output
    assert "Traceback" not in r.output and not list(out.rglob("*.parquet")) and lock.exists()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    lock.write_text(f"pid {dead.pid} on {socket.gethostname()}")  # a killed run's lock
    r = runner.invoke(app, args)
    _finished(r)
    assert len(list(out.rglob("*.parquet"))) == 6 and not lock.exists()
    lock.write_text(f"pid {os.getpid()} on {socket.gethostname()}")  # a live run resuming the whole folder
    r = runner.invoke(app, args)
    assert r.exit_code == 2 and "another run is writing into it" in r.output, r.output


def test_a_run_that_waited_for_anothers_lock_says_so_and_a_resume_says_why_it_measures(fleet, tmp_path):
    """Issue 51, item 11: a second run that finds the first's lock freed within the wait says it waited (how long,
    for which pid and host) and resumed; a resume that keeps every partition says why it measures every hole."""
    import threading

    import metrology.io.holeout as holeout

    out = tmp_path / "out"
    args = ["measure", str(fleet / "log"), "--layout", str(fleet / "calibrated.toml"), "--out", str(out)]
    _finished(runner.invoke(app, args))  # the first run wrote every partition
    lock = out / holeout.LOCK
    who = f"pid {os.getpid()} on {socket.gethostname()}"
    lock.write_text(who)  # a live run writing: it ends 1 s into this run's wait
    threading.Timer(1.0, lambda: lock.unlink()).start()
    r = runner.invoke(app, args)
    _finished(r)
    assert re.search(rf"warning: --out \S+: waited [0-4]\.\d s for another run writing into it \({who}\), which "
                     rf"ended; this run resumes", r.stderr), r.stderr
    assert ("resumed: 6 of 6 partition(s) kept as an earlier run wrote them, 0 written (every hole measured again: "
            "the summary, the verdict and the drift watch cover the whole log)") in r.stdout
    r = runner.invoke(app, args)  # one after the other: nothing to wait for, nothing said of it
    _finished(r)
    assert "waited" not in r.stderr and "resumed: 6 of 6" in r.stdout


def test_the_resume_manifest_names_the_log_by_its_resolved_path(fleet, tmp_path, monkeypatch):
    """``./log`` and ``log`` are the same run: the second resumes (writes nothing), not refused."""
    monkeypatch.chdir(fleet)
    out = tmp_path / "out"
    r = runner.invoke(app, ["measure", "./log", "--layout", "calibrated.toml", "--out", str(out), "--json"])
    _finished(r)
    r = runner.invoke(app, ["measure", "log", "--layout", "./calibrated.toml", "--out", str(out), "--json"])
    _finished(r)
    assert json.loads(r.stdout)["partitions_written"] == 0


def test_metros_local_cluster_runs_without_a_dashboards_monitors_and_restores_the_config(fleet):
    """The LocalCluster of --workers runs its workers with QUIET_CLUSTER (no profiler, the monitors
    every second: with a worker per core they took the tasks' time), and leaves Dask's config as
    it was."""
    import dask.config

    from metrology.measure.fleet import QUIET_CLUSTER, connect

    before = {k: dask.config.get(k) for k in QUIET_CLUSTER}
    assert before != QUIET_CLUSTER  # Dask's defaults differ, or the test shows nothing
    with connect(workers=1) as client:
        seen = client.run(lambda: {k: dask.config.get(k) for k in QUIET_CLUSTER})
    assert list(seen.values()) == [QUIET_CLUSTER]
    assert {k: dask.config.get(k) for k in QUIET_CLUSTER} == before


def test_a_bad_log_with_workers_is_its_one_line_error_and_the_cluster_started_meanwhile_is_closed(fleet, tmp_path):
    """--workers starts the cluster while the inputs are read: a bad log is still its own one-line
    error (exit 2, nothing written), and the cluster is closed, its worker processes gone. Dask's
    port 8787 taken (another cluster) adds no warning line."""
    with socket.socket() as busy:
        try:
            busy.bind(("", 8787))
            busy.listen()
        except OSError:  # taken already: the same case
            pass
        bad = tmp_path / "bad.csv"  # read once the cluster is starting (a missing file is refused before it)
        bad.write_text("hole_id,when\nH1,2026-11-25T08:00:00Z\n", encoding="utf-8")
        r = runner.invoke(app, ["measure", str(bad), "--layout", str(fleet / "calibrated.toml"),
                                "--out", str(tmp_path / "out"), "--workers", "2"])
    assert r.exit_code == 2, r.output
    assert r.output.strip().count("\n") == 0 and "bad.csv" in r.output and r.output.startswith("error: ")
    assert not (tmp_path / "out").exists()
    assert not _worker_processes()


def _worker_processes() -> list:
    """This process's LocalCluster worker processes alive: forked by its forkserver (a child of
    this process), or spawned (where there is no forkserver)."""
    import psutil

    me, alive = psutil.Process(), []
    for p in me.children(recursive=True):
        try:
            if p.ppid() != me.pid or "spawn_main" in " ".join(p.cmdline()):
                alive.append(p)
        except psutil.NoSuchProcess:  # ended meanwhile
            pass
    return alive


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_local_clusters_workers_are_forked_with_what_they_need_imported_and_one_blas_thread(tmp_path):
    """--workers forks its worker processes from a forkserver that has imported Dask and metro's
    measuring (WORKER_PRELOAD), not spawned to import them each, and the block's end leaves no
    worker running (a worker killed and restarted is forked again: the killed-worker test). numpy
    was loaded there with the environment Dask gives a spawned worker: one BLAS thread, a worker per
    core (the tests' own process has it already, so a new process without it checks that)."""
    from metrology.measure.fleet import WORKER_PRELOAD, connect

    with connect(workers=2) as client:
        seen = client.run(lambda: (WORKER_PRELOAD in sys.modules, os.getppid()))
        assert len(_worker_processes()) == 2
    assert [v[0] for v in seen.values()] == [True, True]
    forkserver = {v[1] for v in seen.values()}
    assert len(forkserver) == 1 and forkserver != {os.getpid()}  # both forked by one forkserver, not spawned by us
    assert not _worker_processes()

    code = """if True:
        import ctypes
        from metrology.measure.fleet import connect

        def blas_threads():  # OpenBLAS's thread count (numpy's wheels bundle it), None without it
            import numpy  # noqa: F401

            libs = sorted({line.split()[-1] for line in open("/proc/self/maps") if "openblas" in line})
            lib = ctypes.CDLL(libs[0]) if libs else None
            for name in ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_", "openblas_get_num_threads"):
                if hasattr(lib, name):
                    return getattr(lib, name)()
            return None

        if __name__ == "__main__":
            print(blas_threads())
            with connect(workers=1) as client:
                print(*client.run(blas_threads).values())
    """
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    script = tmp_path / "blas.py"
    script.write_text(code)
    out = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    here, worker = out.stdout.split()
    assert here != "None", "numpy without OpenBLAS (numpy's Linux wheels bundle it): the check reads nothing"
    assert worker == "1"
    assert int(here) > 1 or os.cpu_count() == 1  # numpy loaded without the environment: a thread a core


def test_each_partitions_drift_watch_link_follows_its_measuring_so_the_feeds_held_stay_bounded(tmp_path):
    """One cell's chain of 32 partitions of 4000 holes on 2 workers: each partition's watch link runs
    as its measuring ends (QUIET_CLUSTER's worker-saturation 1.0), not after the partition queued
    behind it, so the workers hold the per-hole feeds of 0-2 partitions waiting for the watch
    (with two such runs at once on 2 cores too). At Dask's 1.1 the chain fell behind and stayed
    behind: 4-6 partitions' feeds held all through the second half (15 at the end of a log of
    600-hole partitions). Whatever the workers' speeds: a partition is measured once the watch has
    been fed the partition two (the cluster's threads) before it; without that, a worker starved of
    CPU (load 13-14 on 2 cores) held the chain back while the other measured on, 4-11 feeds held and
    this test failed. The results are the single process's."""
    from distributed import get_task_stream

    from metrology.io.holelog import open_log
    from metrology.io.holeout import PartitionedOutput
    from metrology.measure.fleet import DaskEngine, connect
    from metrology.measure.holes import Settings
    from metrology.measure.run import measure_log

    lay = calibrated_layout()
    cols, _, _ = hole_log(lay, n=32 * 4000, seed=4, angle_deg=(1, 4))
    t = pa.table(cols).drop_columns(["cell"])
    for k in range(32):
        d = tmp_path / "log" / "cell=C1" / f"part={k:02d}"
        d.mkdir(parents=True)
        pq.write_table(t.slice(4000 * k, 4000), d / "part-0.parquet")
    log = open_log(tmp_path / "log", lay.names)
    one = measure_log(log, lay, Settings(), output=PartitionedOutput(tmp_path / "one", {}))
    with connect(workers=2) as client:
        # a first run warms both workers (their first partition imports metro: on a fresh machine it
        # took as long as ten others, and the chain waited for it meanwhile); the second is watched
        for name in ("warm", "dask"):
            with get_task_stream(client) as ts:
                out = PartitionedOutput(tmp_path / name, {})
                two = measure_log(log, lay, Settings(), DaskEngine(client), output=out)
                out.release()
    assert two.summary.counts() == one.summary.counts() and two.rows == one.rows == 128000
    span = {}
    for task in ts.data:
        kind, i = task["key"].split("-")[1:3]
        run = [s for s in task["startstops"] if s["action"] == "compute"][-1]
        span[kind, int(i)] = (run["start"], run["stop"])
    held = [sum(span["measure", j][1] <= span["measure", i][0] < span["watch", j][0] for j in range(32))
            for i in range(32)]
    # measured, not yet watched, as each partition's measuring starts: in the second half (the
    # first partitions can hold the chain back meanwhile)
    assert max(held[16:]) <= 3, held


def test_dask_weighs_a_measured_partition_by_its_arrays(tmp_path):
    """``dask.sizeof`` of a partition's piece is its feed's and table's bytes (not the 100 bytes of
    ``sys.getsizeof``'s default): the scheduler places a watch link beside the feed it takes, and a
    worker's memory accounting sees what it holds."""
    from dask.sizeof import sizeof

    from metrology.io.holelog import open_log
    from metrology.measure.holes import Settings
    from metrology.measure.run import measure_partition

    lay = calibrated_layout()
    cols, _, _ = hole_log(lay, n=2000, seed=2)
    path = tmp_path / "log.parquet"
    pq.write_table(pa.table(cols), path)
    log = open_log(path, lay.names)
    piece, end = list(measure_partition(log, log.partitions[0], lay, Settings(), rows=True))
    f = piece.feed
    arrays = sum(a.nbytes for a in (f.row, f.cell.codes, f.panel.codes, f.time_s, f.charted, f.rho_mm, f.noise_sd_mm,
                                    f.signature))
    assert sizeof(f) >= arrays + f.hole_id.nbytes > 2000 * 80
    assert sizeof(piece) >= sizeof(f) + piece.table.nbytes
    assert sizeof(end) < 1000  # the partition's end: no feed, no rows

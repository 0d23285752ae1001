"""The Dask path (metro[fleet]): the same per-hole results, summary and alarms as one process, on a
LocalCluster and on a real `dask scheduler` with two `dask worker` processes on localhost."""

import json
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

pytest.importorskip("distributed")
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


def _run(fleet, out, *extra):
    r = runner.invoke(app, ["measure", str(fleet / "log"), "--layout", str(fleet / "calibrated.toml"),
                            "--out", str(out), "--json", *extra])
    assert r.exit_code in (0, 1), r.output
    s = json.loads(r.stdout)
    s.pop("engine")
    s["sources"].pop("out")
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
                                          env=env))
        from distributed import Client

        with Client(address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
            assert len(c.scheduler_info()["workers"]) == 2
        two = _run(fleet, tmp_path / "cluster", "--scheduler", address)
        one = _run(fleet, tmp_path / "one")
        assert one == two
        _same_files(tmp_path / "one", tmp_path / "cluster")
    finally:
        for p in procs[::-1]:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()

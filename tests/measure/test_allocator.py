"""``tune_allocator`` switches glibc's heap thresholds and pyarrow's memory pool for the whole process: the
library never calls it, the edges that own a process do (``metro measure``'s command, the Dask workers' setup).
Each case runs in a fresh interpreter: the pool a process starts with is pyarrow's own (mimalloc or jemalloc)."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

LOG = textwrap.dedent("""
    import pyarrow as pa, pyarrow.parquet as pq
    from metrology.io.layout import save_layout
    from tests.measure.helpers import calibrated_layout, hole_log
    start = pa.default_memory_pool().backend_name
    save_layout(calibrated_layout(), "{tmp}/cal.toml")
    cols, _, _ = hole_log(calibrated_layout(), n=300, seed=2)
    pq.write_table(pa.table(cols), "{tmp}/log.parquet")
""")


def _run(code: str) -> list:
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


def test_measuring_a_log_through_the_library_leaves_the_process_as_it_was(tmp_path):
    out = _run(LOG.format(tmp=tmp_path) + textwrap.dedent(f"""
        from metrology.io.holelog import open_log
        from metrology.io.layout import load_layout
        from metrology.jobs.measure import MeasureOptions, measure_files
        from metrology.measure.holes import Settings
        from metrology.measure.run import OneProcess, measure_log
        lay = load_layout("{tmp_path}/cal.toml")
        r = measure_log(open_log("{tmp_path}/log.parquet", lay.names), lay, Settings(), OneProcess())
        measure_files("{tmp_path}/log.parquet", "{tmp_path}/cal.toml", MeasureOptions(out=Path("{tmp_path}/o.parquet")))
        print(start, pa.default_memory_pool().backend_name, r.rows)
    """).replace("from metrology.io.holelog", "from pathlib import Path\nfrom metrology.io.holelog", 1))
    start, after, rows = out
    assert start != "system" and after == start and rows == "300"


def test_the_measure_command_keeps_glibcs_heap_for_its_batches(tmp_path):
    out = _run(LOG.format(tmp=tmp_path) + textwrap.dedent(f"""
        from typer.testing import CliRunner
        from cli.main import app
        r = CliRunner().invoke(app, ["measure", "{tmp_path}/log.parquet", "--layout", "{tmp_path}/cal.toml",
                                     "--out", "{tmp_path}/o.parquet"])
        assert r.exit_code in (0, 1), r.output
        print(start, pa.default_memory_pool().backend_name)
    """))
    assert out[0] != "system" and out[1] == "system"


def test_a_dask_worker_is_set_up_by_its_plugin_not_by_the_tasks():
    pytest.importorskip("distributed")
    out = _run(textwrap.dedent("""
        import pyarrow as pa
        from distributed.diagnostics.plugin import WorkerPlugin
        from metrology.measure.fleet import _tuned_heap
        plugin = _tuned_heap()
        start = pa.default_memory_pool().backend_name
        assert isinstance(plugin, WorkerPlugin)
        plugin.setup(None)
        print(start, pa.default_memory_pool().backend_name)
    """))
    assert out[0] != "system" and out[1] == "system"
    import inspect

    from metrology.measure import fleet, run

    assert "tune_allocator" not in inspect.getsource(fleet._task)
    assert "tune_allocator" not in inspect.getsource(run.OneProcess)

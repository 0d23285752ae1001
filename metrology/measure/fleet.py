"""The same measurement on a Dask cluster: one task per partition of a partitioned log.

Each task runs :func:`metrology.measure.run.measure_partition` on one partition (reading it,
measuring it, writing its result file atomically beside the others) and returns its summary
and its drift-watch :class:`~metrology.measure.run.Feed`. The client merges the summaries and
feeds the watch in the log's order as the tasks finish, so per-hole results, summary and alarms
are those of the single-process run. ``dask.distributed`` is imported only here.
"""

from __future__ import annotations

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.io.holelog import HoleLog
from metrology.measure.holes import Settings
from metrology.measure.run import MeasureResult, Watch, measure_partition, tune_allocator
from metrology.measure.summary import FleetSummary

__all__ = ["connect", "measure_log_dask"]


def connect(workers: int | None = None, scheduler: str | None = None):
    """A ``distributed.Client``: to a running scheduler (``tcp://host:port``), or to a new
    LocalCluster of ``workers`` single-threaded worker processes. ValueError when Dask is missing
    or the scheduler cannot be reached."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ValueError("--workers/--scheduler need Dask: pip install \"metro[fleet]\"") from None
    if scheduler is not None:
        try:
            return Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
    if workers is None or workers < 1:
        raise ValueError(f"--workers must be at least 1, got {workers}")
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    return Client(cluster)


class _Rows:
    """A task's per-hole results kept to be sent back (an output that is one file)."""

    def __init__(self):
        self.tables = []

    def write(self, table) -> None:
        self.tables.append(table)

    def table(self):
        import pyarrow as pa

        return pa.concat_tables(self.tables) if self.tables else None


def _task(log, part, layout, settings, output):
    """One partition measured on a worker: its result, and its per-hole results when the output is
    one file (written by the client, in order) rather than a folder (written here)."""
    tune_allocator()  # a worker started by Dask's nanny maps every batch array otherwise (run.tune_allocator)
    if output is not None:
        return measure_partition(log, part, layout, settings, output=output), None
    rows = _Rows()
    return measure_partition(log, part, layout, settings, sink=rows), rows.table()


def measure_log_dask(client, log: HoleLog, layout: SensorLayout, settings: Settings, output,
                     progress=None, by_panel: bool = False, sink=None) -> MeasureResult:
    """Measure ``log`` on ``client``'s workers, one task per partition, results into ``output`` (a
    folder: each task writes its partition's file) or ``sink`` (one file: the client writes each
    task's rows, in the log's order)."""
    if output is not None:
        output.begin()
    futures = [client.submit(_task, log, part, layout, settings, output, pure=False, key=f"metro-measure-{i}-{part.relative}")
               for i, part in enumerate(log.partitions)]
    summary = FleetSummary(float(np.degrees(settings.tolerance)))
    watch = Watch(layout.names, by_panel)
    rows = written = 0
    for fut in futures:  # in the log's order: the watch needs it; later tasks run meanwhile
        r, table = fut.result()
        if table is not None and sink is not None:
            sink.write(table)
        summary.merge(r.summary)
        watch.feed(r.feed)
        rows += r.rows
        written += r.written
        if progress is not None:
            progress(r.rows)
        fut.release()
    watch.finish()
    return MeasureResult(summary, watch, rows, len(log.partitions), written)

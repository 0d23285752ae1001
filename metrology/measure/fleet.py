"""The same measurement on a Dask cluster: one task per partition of a partitioned log.

Each task runs :func:`metrology.measure.run.measure_partition` on one partition (reading it,
measuring it, writing its result file atomically beside the others); its drift-watch
:class:`~metrology.measure.run.Feed` goes, on the workers, to a chain of watch tasks per cell in the
log's order, and only its summary to the client, which merges the summaries and the chains' final
watches. Per-hole results, summary and alarms are those of the single-process run.
``dask.distributed`` is imported only here.
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


def _small(measured):
    """What the client needs of a measured partition: its result without the feed (the holes the
    watch needs stay on the workers), and its rows when the output is one file."""
    import dataclasses

    r, table = measured
    return dataclasses.replace(r, feed=None), table


def _watch_step(prev, measured, sensors, by_panel):
    """One link of a chain of partitions: the drift watch ``prev`` (None: a new one) fed this
    partition's holes, in the log's order; runs on a worker, where the partition's feed is."""
    import copy

    # a copy: the previous link's result stays as it was (a link re-run after a lost worker starts from it)
    watch = Watch(tuple(sensors), by_panel) if prev is None else copy.deepcopy(prev)
    watch.feed(measured[0].feed)
    return watch


def _chains(log: HoleLog) -> dict:
    """The partitions' indices by drift-watch chain: one chain per ``cell=`` key when every
    partition has one (each cell's chart is its own time series: the chains run in parallel),
    else one chain of all the partitions in the log's order."""
    if log.partitions and all("cell" in p.keys for p in log.partitions):
        chains = {}
        for i, p in enumerate(log.partitions):
            chains.setdefault(p.keys["cell"], []).append(i)
        return chains
    return {None: list(range(len(log.partitions)))}


def measure_log_dask(client, log: HoleLog, layout: SensorLayout, settings: Settings, output,
                     progress=None, by_panel: bool = False, sink=None) -> MeasureResult:
    """Measure ``log`` on ``client``'s workers, one task per partition, results into ``output`` (a
    folder: each task writes its partition's file) or ``sink`` (one file: the client writes each
    task's rows, in the log's order).

    The drift watch runs on the workers too: a chain of tasks per cell (:func:`_chains`) feeds a
    cell's partitions to its watch in the log's order, each link where its partition was measured;
    the client merges the small summaries and, at the end, the chains' watches (a few numbers a
    cell), so its work does not grow with the holes but with the partitions."""
    if output is not None:
        output.begin()
    names = [f"{i}-{part.relative}" for i, part in enumerate(log.partitions)]
    measured = [client.submit(_task, log, part, layout, settings, output, pure=False, key=f"metro-measure-{n}")
                for n, part in zip(names, log.partitions)]
    small = [client.submit(_small, m, pure=False, key=f"metro-small-{n}") for n, m in zip(names, measured)]
    watches = []
    for chain in _chains(log).values():
        w = None
        for i in chain:
            w = client.submit(_watch_step, w, measured[i], layout.names, by_panel, pure=False,
                              key=f"metro-watch-{names[i]}")
        watches.append(w)
    del measured  # the scheduler keeps each until its small result and its watch link have it
    try:
        return _collect(client, log, layout, settings, small, watches, progress, by_panel, sink)
    except _lost() as exc:  # a one-line error; the partitions written so far are kept for a resume
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else "no detail"
        raise ValueError(f"the Dask cluster stopped the run ({type(exc).__name__}: {detail}): partitions already "
                         f"written are kept; a re-run with the same --out resumes") from None


def _lost():
    """The exceptions of a cluster that lost the run (a worker killed repeatedly, the scheduler gone)."""
    import asyncio
    import concurrent.futures

    from distributed import KilledWorker

    return (KilledWorker, concurrent.futures.CancelledError, asyncio.CancelledError, TimeoutError)


def _collect(client, log, layout, settings, small, watches, progress, by_panel, sink) -> MeasureResult:
    """The client's part: the partitions' small results in the log's order, then the chains' watches."""
    summary = FleetSummary(float(np.degrees(settings.tolerance)))
    rows = written = 0
    for fut in small:  # in the log's order: the rows of a one-file output are written so
        r, table = fut.result()
        if table is not None and sink is not None:
            sink.write(table)
        summary.merge(r.summary)
        rows += r.rows
        written += r.written
        if progress is not None:
            progress(r.rows)
        fut.release()
    watch = Watch(layout.names, by_panel)
    for w in client.gather(watches):  # each chain's cells are its own
        watch.charts.update(w.charts)
        watch.last.update(w.last)
    watch.finish()
    return MeasureResult(summary, watch, rows, len(log.partitions), written)

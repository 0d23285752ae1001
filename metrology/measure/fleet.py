"""The engine of a Dask cluster: one task per partition, for :func:`metrology.measure.run.measure_log`.

Each task runs :func:`metrology.measure.run.measure_partition` on one partition (reading it,
measuring it, writing its result file atomically beside the others) and keeps its drift-watch
:class:`~metrology.measure.run.Feed` on the workers, where a chain of watch tasks per cell feeds
them in the log's order; the client receives each partition's summary (a few kB; and its rows
when the output is one file) and, at the end, the chains' watches. :func:`connect` opens the
cluster and closes what it opened. ``dask.distributed`` is imported only here (and by the
forkserver that its LocalCluster's workers are forked from: :mod:`metrology.measure.preload`).
"""

from __future__ import annotations

import contextlib
from typing import Iterator

from metrology.core.layout import SensorLayout
from metrology.io.holelog_reader import HoleLog
from metrology.measure.holes import Settings
from metrology.measure.run import Feed, Piece, Watch, measure_partition

__all__ = ["connect", "DaskEngine", "QUIET_CLUSTER", "WORKER_PRELOAD"]

#: s, how long :func:`connect` tries to reach a running scheduler (Dask retries a refused connection)
CONNECT_TIMEOUT_S = 10

#: Dask settings of the LocalCluster :func:`connect` starts (a running scheduler keeps its own). It has
#: no dashboard, so the workers' statistical profiler (a stack sample every 10 ms) and the system
#: monitor (every 0.5 s) feed nothing anyone sees; the event loops' health tick (every 20 ms) and the
#: memory monitor (every 0.1 s: a task holds one partition, bounded) run every second. With one worker
#: a core is spare for them; with a worker per core they take the tasks' time. Measured on 2 cores, 2
#: idle workers: 0.12 -> 0.013 cores, client and workers (``benchmarks/bench_measure.py``, ``dask_idle``).
#: ``worker-saturation`` 1.0: a worker is sent its next partition when it has nothing to run, so a
#: partition's watch link runs as its measuring ends, beside its feed (at Dask's 1.1 a worker held a
#: second partition queued and ran it first: the watch chain fell behind, the workers held 4-6
#: partitions' feeds waiting for it instead of 0-2, and its links moved feeds between workers).
QUIET_CLUSTER = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.scheduler.worker-saturation": 1.0,
}

#: the scheduler's own HTTP server (health and metrics, no dashboard) on a free port of this host: on
#: Dask's 8787 a second run at once warned "Port 8787 is already in use", on every interface
_NO_PORT_8787 = {"dashboard_address": "127.0.0.1:0"}


@contextlib.contextmanager
def connect(workers: int | None = None, scheduler: str | None = None):
    """A ``distributed.Client`` for a ``with`` block: to a running scheduler (``tcp://host:port``),
    or to a new LocalCluster of ``workers`` single-threaded worker processes, which the block's end
    closes (a running scheduler is left running). ValueError when Dask is missing or the scheduler
    cannot be reached."""
    import importlib.util

    if importlib.util.find_spec("distributed") is None:
        raise ValueError("--workers/--scheduler need Dask: pip install \"metro[fleet]\"")
    if scheduler is None and (workers is None or workers < 1):
        raise ValueError(f"--workers must be at least 1, got {workers}")
    # a new cluster's workers are forked from a forkserver that has imported what they need: started
    # first, it imports while Dask is imported here (_forkserver); where there is none, they are spawned
    forked = scheduler is None and _forkserver()
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
        with client:
            client.register_plugin(_tuned_heap())
            yield client
        return
    import dask.config

    # processes of one thread each: the per-hole maths holds the GIL in parts (pyarrow, Python loops);
    # without a dashboard, and without the monitors that only feed one (QUIET_CLUSTER)
    start = {"distributed.worker.multiprocessing-method": "forkserver"} if forked else {}
    with dask.config.set({**QUIET_CLUSTER, **start}), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                         scheduler_kwargs=_NO_PORT_8787) as cluster, \
            Client(cluster) as client:
        client.register_plugin(_tuned_heap())
        yield client


def _tuned_heap():
    """A worker plugin that keeps glibc's heap on every worker of the cluster, those that join later too
    (:func:`metrology.measure.run.tune_allocator`: a worker started by Dask's nanny maps every batch array
    otherwise); the setup of the workers' processes, never of the library's calls."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class TunedHeap(WorkerPlugin):
        name = "metro-tuned-heap"

        def setup(self, worker):
            from metrology.measure.run import tune_allocator

            tune_allocator()

    return TunedHeap()


#: the module the forkserver imports before it forks a LocalCluster's workers (:func:`_forkserver`)
WORKER_PRELOAD = "metrology.measure.preload"


def _forkserver() -> bool:
    """Start Python's forkserver, with :data:`WORKER_PRELOAD` imported, for a LocalCluster's workers
    to be forked from; True where the platform has one (POSIX), else their processes are spawned.

    Why: a spawned worker is a new interpreter that imports Dask as it starts and metro's measuring
    in its first partition, every worker on its own, on the cores the others measure on (about 0.7 s
    of a core each here). The forkserver imports them once, started before the client imports
    Dask, and Dask forks each worker from it (its ``multiprocessing-method``, the default start of
    Python 3.14). It serves this process until it exits: a later cluster forks from it at once, and
    one running already keeps the preload it was started with. The forkserver is the process's own
    (``multiprocessing``'s): other forkserver processes this program starts later come from it too,
    with metro's modules loaded."""
    import multiprocessing
    import multiprocessing.forkserver

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    multiprocessing.get_context("forkserver").set_forkserver_preload([WORKER_PRELOAD])
    multiprocessing.forkserver.ensure_running()
    return True


def _task(log, part, layout, settings, output, rows, after=None):
    """One partition measured on a worker: one :class:`Piece` (its pieces joined: the summaries
    merged in order, as :func:`measure_log` merges a partition's pieces; the feed and rows
    concatenated). The per-hole results go to the partition's file (a folder output), or back to
    the client (``rows``: a one-file output). ``after``, unread: the watch link the partition waits for
    (:meth:`DaskEngine.pieces`)."""
    import pyarrow as pa

    pieces = list(measure_partition(log, part, layout, settings, output=output, rows=rows))
    summary = pieces[0].summary
    for p in pieces[1:]:
        summary.merge(p.summary)
    tables = [p.table for p in pieces if p.table is not None]
    return Piece(summary, sum(p.rows for p in pieces), Feed.concat(p.feed for p in pieces if p.feed is not None),
                 pa.concat_tables(tables) if tables else None, True, pieces[-1].written)


def _small(piece: Piece) -> Piece:
    """What the client needs of a measured partition: its piece without the feed (the holes the
    watch needs stay on the workers)."""
    import dataclasses

    return dataclasses.replace(piece, feed=None)


def _watch_step(prev, piece, sensors, by_panel):
    """One link of a chain of partitions: the drift watch ``prev`` (None: a new one) fed this
    partition's holes, in the log's order; runs on a worker, where the partition's feed is."""
    import copy

    # a copy: the previous link's result stays as it was (a link re-run after a lost worker starts from it)
    watch = Watch(tuple(sensors), by_panel) if prev is None else copy.deepcopy(prev)
    watch.feed(piece.feed)
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


def _lost():
    """The exceptions of a cluster that lost the run (a worker killed repeatedly, the scheduler gone)."""
    import asyncio
    import concurrent.futures

    from distributed import KilledWorker

    return (KilledWorker, concurrent.futures.CancelledError, asyncio.CancelledError, TimeoutError)


@contextlib.contextmanager
def _one_line():
    """A cluster that lost the run: a one-line ValueError; the partitions written so far are kept."""
    try:
        yield
    except _lost() as exc:
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else "no detail"
        raise ValueError(f"the Dask cluster stopped the run ({type(exc).__name__}: {detail}): partitions already "
                         f"written are kept; a re-run with the same --out resumes") from None


class DaskEngine:
    """The partitions of a log measured on ``client``'s workers, one task each, for
    :func:`metrology.measure.run.measure_log` (:meth:`pieces`: one piece per partition, in the log's
    order; :meth:`watches`: the chains' watches, when all pieces are in).

    The drift watch runs on the workers: a chain of tasks per cell (:func:`_chains`) feeds a cell's
    partitions to its watch in the log's order, each link where its partition was measured; the
    client merges the small summaries and, at the end, the chains' watches (a few numbers a cell),
    so its work does not grow with the holes but with the partitions."""

    def __init__(self, client, name: str = "Dask"):
        self.client = client
        self.name = name
        self._watches = []

    def plan(self, log: HoleLog, output=None) -> HoleLog:
        """The log as tasks: its partitions; a single Parquet file into one output file, its row groups
        (a CSV file is one task)."""
        return log.by_row_group() if output is None else log

    def pieces(self, log: HoleLog, layout: SensorLayout, settings: Settings, output=None, rows: bool = False,
               by_panel: bool = False) -> Iterator[Piece]:
        client = self.client
        names = [f"{i}-{part.relative}" for i, part in enumerate(log.partitions)]
        # a chain's partition is measured once its watch has been fed the partition `ahead` before it, so that of
        # the partitions before it at most `ahead` - 1 are measured and not yet watched (their feeds held on the
        # workers) whatever the workers' speeds: without it a worker starved of CPU held the chain back while the
        # other measured on (up to 5 feeds held at load 14 on 2 cores); `ahead`, the cluster's threads, keeps every
        # thread measuring while the chain keeps up
        chains = list(_chains(log).values())
        chain_of = {i: k for k, chain in enumerate(chains) for i in chain}
        with _one_line():
            ahead = max(sum(client.nthreads().values()), 1)
            links, small = [[] for _ in chains], []  # each chain's watch links so far; each partition's small piece
            for i, (n, part) in enumerate(zip(names, log.partitions)):
                chain = links[chain_of[i]]
                after = chain[-ahead] if len(chain) >= ahead else None
                measured = client.submit(_task, log, part, layout, settings, output, rows, after, pure=False,
                                         key=f"metro-measure-{n}")
                small.append(client.submit(_small, measured, pure=False, key=f"metro-small-{n}"))
                chain.append(client.submit(_watch_step, chain[-1] if chain else None, measured, layout.names,
                                           by_panel, pure=False, key=f"metro-watch-{n}"))
            self._watches = [chain[-1] for chain in links if chain]
            # the scheduler keeps each until its small result and its watch link (and the partition `ahead` after
            # it) have it
            measured = chain = after = links = None
            for fut in small:  # in the log's order: the rows of a one-file output are written so
                piece = fut.result()
                fut.release()
                yield piece

    def watches(self) -> list:
        with _one_line():
            return self.client.gather(self._watches)

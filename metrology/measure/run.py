"""A hole log measured: every partition's holes, the fleet summary and the drift watch.

One driver, :func:`measure_log`, merges the summaries, feeds the drift watch, counts the holes
and reports progress, whatever the engine: it takes an in-order iterator of :class:`Piece`
(partition results) that the engine supplies (as xarray's ``open_mfdataset`` has one loop and
``parallel=True`` only wraps the per-file call in ``dask.delayed``). The unit of work is one
partition (:func:`measure_partition`: its batches measured, written and summed up, each batch a
piece). :class:`OneProcess` runs it here, partition after partition, piece by piece (memory
bounded by one batch); :class:`metrology.measure.fleet.DaskEngine` runs it on Dask, one task per
partition, and hands back one piece per partition in the log's order. The results are the same.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Iterator, Protocol

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.io.arrays import from_numpy, to_numpy
from metrology.io.holelog_reader import HoleLog, Partition
from metrology.io.holelog_schema import CELL, INTERNAL, PANEL, TIME_S, text_codes
from metrology.io.names import utc
from metrology.measure.batch import Labels
from metrology.measure.chart import CusumChart
from metrology.measure.holes import HoleBatch, Settings, measure_batch
from metrology.measure.summary import FleetSummary

if TYPE_CHECKING:
    import pyarrow as pa

    from metrology.io.holeout import PartitionedOutput

__all__ = ["Feed", "Watch", "Piece", "MeasureResult", "Engine", "OneProcess", "measure_partition", "measure_log",
           "tune_allocator"]

_TUNED = False


def tune_allocator() -> None:
    """Let glibc keep the per-batch temporaries (up to 32 MB each) on its heap instead of mapping
    and unmapping them batch after batch. Dask's nanny starts its workers with
    ``MALLOC_TRIM_THRESHOLD_=65536``, which fixes glibc's mmap threshold at 128 kB: every array of a
    batch then costs page faults, and a partition took 0.66 s of CPU instead of 0.21 s (0.17 s with
    this setting; 125 000 holes, this machine). Arrow's buffers are taken from the same heap. A no-op where
    the C library is not glibc.

    It changes the whole process (glibc's thresholds, pyarrow's default memory pool), so the library never
    calls it: the edges that own a process do (``metro measure``'s command, the Dask workers' setup,
    :func:`metrology.measure.fleet.connect`, and the forkserver they are forked from,
    :mod:`metrology.measure.preload`)."""
    global _TUNED
    if _TUNED:
        return
    _TUNED = True
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return
    M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
    mallopt(M_MMAP_THRESHOLD, 32 << 20)
    mallopt(M_TRIM_THRESHOLD, 64 << 20)
    # Arrow's buffers (the batch read, the columns written) from the same heap: its own pool (mimalloc) hands
    # freed pages back and faults them in again batch after batch (0.4-0.5 s of system CPU per million holes)
    import pyarrow as pa

    pa.set_memory_pool(pa.system_memory_pool())


@dataclass(frozen=True)
class Feed:
    """What the drift watch needs of some holes of one partition, in log order.

    Attributes
    ----------
    log : HoleLog; part : Partition, where the holes are (errors name them by :meth:`HoleLog.locate`)
    row : (m,) int, each hole's row in the partition's file (0-based)
    cell, panel : Labels, each hole's cell and panel by a dictionary (its code, (m,) int64, into its values): a
        million holes' text compared and sorted cost the watch 0.1 s of CPU, their codes a hundredth
    hole_id : pyarrow.StringArray, length m (kept as Arrow: only the alarms' holes become Python strings)
    time_s : (m,) float, s since 1970-01-01 UTC
    charted : (m,) bool, measured on all 4 sensors (the chart takes those)
    rho_mm, noise_sd_mm : (m,) float, mm (NaN where not charted); signature : (m, 4) float, mm per mm
    """

    log: HoleLog
    part: Partition
    row: np.ndarray
    cell: Labels
    panel: Labels
    hole_id: "pa.StringArray"
    time_s: np.ndarray
    charted: np.ndarray
    rho_mm: np.ndarray
    noise_sd_mm: np.ndarray
    signature: np.ndarray

    def locate(self, row: int) -> str:
        """How an error names the hole at ``row`` of the partition's file."""
        return self.log.locate(self.part, row)

    def __sizeof__(self) -> int:
        """Bytes, its arrays': what Dask's scheduler weighs (``dask.sizeof`` falls back to
        ``sys.getsizeof``) when it places a watch link beside its partition's feed or moves the feed."""
        arrays = sum(v.nbytes for v in vars(self).values() if isinstance(v, np.ndarray))
        return object.__sizeof__(self) + arrays + self.cell.codes.nbytes + self.panel.codes.nbytes + self.hole_id.nbytes

    @classmethod
    def of(cls, batch: HoleBatch, log: HoleLog | str, part: Partition | None = None, first_row: int = 0) -> "Feed":
        """The feed of ``batch``, whose first hole is row ``first_row`` of ``part``'s file (``log`` a
        name: holes in memory, errors name their rows in it as in a Parquet file's)."""
        if isinstance(log, str):
            from metrology.io.holelog_parquet import ParquetLog

            log = ParquetLog(log, (), (), display=log)
        if part is None:
            part = Partition(log.display, log.display, {})
        t = batch.columns
        n = len(batch)
        ch = batch.chart
        charted = np.zeros(n, bool)
        charted[ch.index] = True
        if ch.index.size == n and ch.signature.ndim == 2:  # every hole charted: the chart's own arrays
            rho, sd, sig = ch.rho_mm, ch.noise_sd_mm, ch.signature
        else:
            rho = np.full(n, np.nan)
            sd = np.full(n, np.nan)
            sig = np.full((n, ch.signature.shape[1] if ch.signature.ndim == 2 else 4), np.nan)
            rho[ch.index] = ch.rho_mm
            sd[ch.index] = ch.noise_sd_mm
            if ch.index.size:
                sig[ch.index] = ch.signature
        return cls(log, part, first_row + np.arange(n), _labels(t.column(CELL), batch.cell),
                   _labels(t.column(PANEL), batch.panel), t.column("hole_id").combine_chunks(), to_numpy(t.column(TIME_S)),
                   charted, rho, sd, sig)

    @classmethod
    def concat(cls, feeds) -> "Feed | None":
        """One feed of a partition's feeds, in order (None for none)."""
        feeds = list(feeds)
        if not feeds:
            return None
        import pyarrow as pa

        rest = (np.concatenate([getattr(f, k) for f in feeds]) for k in
                ("time_s", "charted", "rho_mm", "noise_sd_mm", "signature"))
        return cls(feeds[0].log, feeds[0].part, np.concatenate([f.row for f in feeds]),
                   Labels.concat([f.cell for f in feeds]), Labels.concat([f.panel for f in feeds]),
                   pa.concat_arrays([f.hole_id for f in feeds]), *rest)


def _labels(col, labels=None) -> Labels:
    """A string column with few values (cell, panel) by its dictionary (``labels``, where the batch has it
    already)."""
    return Labels(*text_codes(col)) if labels is None else labels


@dataclass
class Watch:
    """Each cell's drift chart, and the time order of each cell's holes.

    Attributes
    ----------
    sensors : tuple of str
    by_panel : bool, a new baseline at each panel (:class:`CusumChart`)
    charts : dict, cell -> CusumChart
    last : dict, cell -> (time_s, where): the cell's last hole so far (s, and how an error names it)
    """

    sensors: tuple
    by_panel: bool = False
    charts: dict = field(default_factory=dict)
    last: dict = field(default_factory=dict)

    def feed(self, f: Feed | None) -> None:
        """Take the next holes of the log, in order; ValueError when a cell's time goes back."""
        if f is None or not len(f.row):
            return
        codes, values = f.cell.codes, f.cell.values
        present = np.flatnonzero(np.bincount(codes, minlength=len(values)))
        panels = np.array(f.panel.values or [""], dtype=str)
        for k in sorted(present.tolist(), key=values.__getitem__):  # by name: cells are independent of each other
            cell = values[k]
            m = codes == k
            t = f.time_s[m]
            rows = f.row[m]
            back = np.flatnonzero(np.diff(t) < 0)
            prev = self.last.get(cell)
            if prev is not None and t[0] < prev[0]:
                raise ValueError(f"{f.locate(rows[0])}: time {utc(t[0])} is before the previous hole of cell "
                                 f"'{cell}' ({prev[1]}, {utc(prev[0])}): a log must be in time order "
                                 f"within each cell")
            if back.size:
                i = int(back[0])
                raise ValueError(f"{f.locate(rows[i + 1])}: time {utc(t[i + 1])} is before the previous hole "
                                 f"of cell '{cell}' ({f.log.line(rows[i])}, {utc(t[i])}): a log must be in time "
                                 f"order within each cell")
            self.last[cell] = (float(t[-1]), f.locate(rows[-1]))
            c = m & f.charted
            if len(self.sensors) == 4 and c.any():
                chart = self.charts.setdefault(cell, CusumChart(str(cell), self.sensors, by_panel=self.by_panel))
                if c.all():  # every hole of the feed charted (one cell, 4 sensors read: the usual): no copies
                    chart.update(f.hole_id, f.time_s, panels[f.panel.codes], f.rho_mm, f.noise_sd_mm, f.signature)
                else:
                    chart.update(f.hole_id.filter(from_numpy(c)), f.time_s[c], panels[f.panel.codes[c]], f.rho_mm[c],
                                 f.noise_sd_mm[c], f.signature[c])

    def join(self, other: "Watch") -> None:
        """Take the charts of ``other``, a watch of other cells (a chain of a Dask run)."""
        self.charts.update(other.charts)
        self.last.update(other.last)

    def finish(self) -> None:
        """The log has ended: size the alarms still waiting for their new baseline."""
        for ch in self.charts.values():
            ch.finish()

    @property
    def alarms(self) -> list:
        return sorted((a for ch in self.charts.values() for a in ch.alarms), key=lambda a: (a.time_s, a.cell))


@dataclass(frozen=True)
class Piece:
    """A part of a partition's result, as an engine hands it to :func:`measure_log`, in the log's order.

    Attributes
    ----------
    summary : FleetSummary, its holes summed up
    rows : int, its holes
    feed : Feed or None, its holes for the drift watch (None: the engine runs the watch itself)
    table : pyarrow.Table or None, its per-hole results to write (a one-file output), else None
    last : bool, the partition's last piece (its file, for a folder output, is written)
    written : bool, with ``last``: this run wrote the partition's results (not an earlier run)
    """

    summary: FleetSummary
    rows: int
    feed: Feed | None = None
    table: "pa.Table | None" = None
    last: bool = True
    written: bool = False

    def __sizeof__(self) -> int:
        """Bytes, its feed's and table's (:meth:`Feed.__sizeof__`)."""
        return (object.__sizeof__(self) + (self.feed.__sizeof__() if self.feed is not None else 0)
                + (self.table.nbytes if self.table is not None else 0))


def measure_partition(log: HoleLog, part: Partition, layout: SensorLayout, settings: Settings,
                      output: "PartitionedOutput | None" = None, rows: bool = False) -> Iterator[Piece]:
    """Measure one partition of ``log``: a :class:`Piece` per batch, in order.

    With ``output`` (a folder output) the partition's results go to its own file, written
    atomically (skipped when an earlier run wrote it: :meth:`PartitionedOutput.done`); with ``rows``
    each piece carries its results (a one-file output, written by the caller in the log's order).
    A last, empty piece says the partition has ended and its file is complete."""
    import contextlib

    tolerance_deg = float(np.degrees(settings.tolerance))
    write = output is not None and not output.done(part.relative)
    keys = list(part.keys)  # in the output's folder names, as in the log's: not in its files (a hive dataset)
    with (output.sink(part.relative) if write else contextlib.nullcontext()) as own:
        for table, first in log.batches(part):
            batch = measure_batch(layout, table, settings)
            summary = FleetSummary(tolerance_deg)
            summary.add(batch)
            public = _public(batch.columns, keys if own is not None else ())
            if own is not None:
                own.write(public)
            yield Piece(summary, len(batch), Feed.of(batch, log, part, first), public if rows else None, last=False)
    # the partition's end, once its file is complete (an empty summary: merging it changes no sum); a
    # one-file output's rows (``rows``) are written by this run too, by the caller. A file this run's
    # worker wrote before it was lost (the partition re-run here finds it) is this run's too.
    yield Piece(FleetSummary(tolerance_deg), 0, None, None, True,
                (output is not None and not output.earlier(part.relative)) or rows)


def _public(table, drop=()):
    """The results as written: without the columns metro added for its own use (and ``drop``)."""
    return table.drop_columns([c for c in (*INTERNAL, *drop) if c in table.column_names])


class Engine(Protocol):
    """What measures a log's partitions: :class:`OneProcess` here, or
    :class:`metrology.measure.fleet.DaskEngine` on a Dask cluster; :func:`measure_log` is the one loop over
    either (no ``if engine ==`` anywhere else)."""

    name: str

    def plan(self, log: HoleLog, output=None) -> HoleLog:
        """The log as this engine's tasks split it."""

    def pieces(self, log: HoleLog, layout: SensorLayout, settings: Settings, output=None, rows: bool = False,
               by_panel: bool = False) -> Iterator[Piece]:
        """Each partition's results (:class:`Piece`), in the log's order."""

    def watches(self) -> list:
        """The drift watches the engine ran itself (empty where every piece carries its feed)."""


class OneProcess:
    """The engine of one process: each partition measured here, in the log's order, batch by batch
    (memory bounded by one batch: the watch is fed each batch as it is measured)."""

    name = "one process"

    def plan(self, log: HoleLog, output=None) -> HoleLog:
        """The log as this engine's tasks split it: as it is."""
        return log

    def pieces(self, log: HoleLog, layout: SensorLayout, settings: Settings, output=None, rows: bool = False,
               by_panel: bool = False) -> Iterator[Piece]:
        for part in log.partitions:
            yield from measure_partition(log, part, layout, settings, output=output, rows=rows)

    def watches(self) -> list:
        """The watches the engine ran itself (None here: every piece carries its feed)."""
        return []


@dataclass
class MeasureResult:
    """A whole log measured.

    Attributes
    ----------
    summary : FleetSummary
    watch : Watch, the drift watch over the whole log (its alarms: :attr:`alarms`)
    rows : int, holes measured
    partitions : int, the log's partitions (the tasks of a Dask run)
    written : int, partitions written by this run (the rest were already there)
    engine : str, what measured it: "one process" or the Dask cluster
    """

    summary: FleetSummary
    watch: Watch
    rows: int
    partitions: int
    written: int
    engine: str = "one process"

    @property
    def alarms(self) -> list:
        return self.watch.alarms


def measure_log(log: HoleLog, layout: SensorLayout, settings: Settings, engine: Engine | None = None, sink=None,
                output: "PartitionedOutput | None" = None, progress=None, by_panel: bool = False) -> MeasureResult:
    """Measure every partition of ``log`` on ``engine`` (:class:`OneProcess` when None; or a
    :class:`metrology.measure.fleet.DaskEngine`), results into ``output`` (a folder: each partition
    its file) or ``sink`` (one file: written here, in the log's order, with ``.write(table)``).

    The one loop of every engine: the pieces come in the log's order; a partition's pieces are
    summed up, then merged into the log's summary (so the sums are the same whatever the engine);
    their feeds go to the drift watch in order; ``progress(rows)`` is called after each piece."""
    engine = OneProcess() if engine is None else engine
    log = engine.plan(log, output)
    tolerance_deg = float(np.degrees(settings.tolerance))
    summary = FleetSummary(tolerance_deg)
    watch = Watch(layout.names, by_panel)
    rows = written = 0
    if output is not None:
        output.begin()
    part = None
    for piece in engine.pieces(log, layout, settings, output=output, rows=sink is not None, by_panel=by_panel):
        if piece.table is not None and sink is not None:
            sink.write(piece.table)
        watch.feed(piece.feed)
        if part is None:
            part = piece.summary
        else:
            part.merge(piece.summary)
        if piece.last:
            summary.merge(part)
            part = None
            written += piece.written
        rows += piece.rows
        if progress is not None:
            progress(piece.rows)
    for w in engine.watches():
        watch.join(w)
    watch.finish()
    return MeasureResult(summary, watch, rows, len(log.partitions), written, engine.name)

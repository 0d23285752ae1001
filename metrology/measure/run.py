"""A hole log measured: every partition's holes, the fleet summary and the drift watch.

The unit of work is one partition (:func:`measure_partition`): its batches measured, written
and summed up, and what the drift chart needs kept as a :class:`Feed`. The single-process run
(:func:`measure_log`) and the Dask run (:mod:`metrology.measure.fleet`) call the same function
per partition and feed the :class:`Watch` in the log's order, so their results are the same.
A partition is read in batches; the single-process run feeds the watch batch by batch, so its
memory is bounded by one batch whatever the log's size.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.io.holelog import HoleLog, Partition
from metrology.measure.chart import CusumChart
from metrology.io.holelog import CELL, INTERNAL, PANEL, TIME_S
from metrology.measure.holes import HoleBatch, Settings, measure_batch
from metrology.measure.summary import FleetSummary

__all__ = ["Feed", "Watch", "PartResult", "MeasureResult", "measure_partition", "measure_log", "tune_allocator"]

_TUNED = False


def tune_allocator() -> None:
    """Let glibc keep the per-batch temporaries (up to 32 MB each) on its heap instead of mapping
    and unmapping them batch after batch. Dask's nanny starts its workers with
    ``MALLOC_TRIM_THRESHOLD_=65536``, which fixes glibc's mmap threshold at 128 kB: every array of a
    batch then costs page faults, and a partition took 0.66 s of CPU instead of 0.21 s (0.17 s with
    this setting; 125 000 holes, this machine). A no-op where the C library is not glibc."""
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


@dataclass(frozen=True)
class Feed:
    """What the drift watch needs of some holes, in log order.

    Attributes
    ----------
    where : str, the partition (for errors)
    first_row : (m,) int, each hole's row in the partition (0-based)
    cell, panel : (m,) str
    hole_id : pyarrow.StringArray, length m (kept as Arrow: only the alarms' holes become Python strings)
    time_s : (m,) float, s
    charted : (m,) bool, measured on all 4 sensors (the chart takes those)
    rho_mm, noise_sd_mm : (m,) float, mm; signature : (m, 4) float
    """

    where: str
    row: np.ndarray
    cell: np.ndarray
    panel: np.ndarray
    hole_id: np.ndarray
    time_s: np.ndarray
    charted: np.ndarray
    rho_mm: np.ndarray
    noise_sd_mm: np.ndarray
    signature: np.ndarray
    csv: bool = False

    def line(self, row: int) -> str:
        """How an error names a row: a CSV's line (the header is line 1), a Parquet file's row."""
        return f"line {row + 2}" if self.csv else f"row {row + 1}"

    @classmethod
    def of(cls, batch: HoleBatch, where: str, first_row: int, csv: bool = False) -> "Feed":
        t = batch.columns
        n = len(batch)
        charted = np.zeros(n, bool)
        charted[batch.chart["index"]] = True
        rho = np.full(n, np.nan)
        sd = np.full(n, np.nan)
        sig = np.full((n, batch.chart["signature"].shape[1] if batch.chart["signature"].ndim == 2 else 4), np.nan)
        rho[batch.chart["index"]] = batch.chart["rho_mm"]
        sd[batch.chart["index"]] = batch.chart["noise_sd_mm"]
        if batch.chart["index"].size:
            sig[batch.chart["index"]] = batch.chart["signature"]
        return cls(where, first_row + np.arange(n), _str(t.column(CELL)), _str(t.column(PANEL)),
                   t.column("hole_id").combine_chunks(), t.column(TIME_S).to_numpy(), charted, rho, sd, sig, csv)

    @classmethod
    def concat(cls, feeds) -> "Feed":
        feeds = list(feeds)
        if not feeds:
            return None
        import pyarrow as pa

        row, cell, panel = (np.concatenate([getattr(f, k) for f in feeds]) for k in ("row", "cell", "panel"))
        rest = (np.concatenate([getattr(f, k) for f in feeds]) for k in
                ("time_s", "charted", "rho_mm", "noise_sd_mm", "signature"))
        return cls(feeds[0].where, row, cell, panel, pa.concat_arrays([f.hole_id for f in feeds]), *rest, feeds[0].csv)


def _iso(t_s: float) -> str:
    import datetime as dt

    return dt.datetime.fromtimestamp(float(t_s), dt.timezone.utc).isoformat().replace("+00:00", "Z")


def _str(col) -> np.ndarray:
    """A string column with few values (cell, panel) as a numpy array, through its dictionary."""
    import pyarrow.compute as pc

    enc = pc.dictionary_encode(col).combine_chunks()
    return np.array(enc.dictionary.to_pylist() or [""], dtype=str)[enc.indices.to_numpy(zero_copy_only=False)]


@dataclass
class Watch:
    """Each cell's drift chart, and the time order of each cell's holes.

    Attributes
    ----------
    sensors : tuple of str; charts : dict, cell -> CusumChart; last : dict, cell -> (time_s, where, row)
    """

    sensors: tuple
    by_panel: bool = False
    charts: dict = field(default_factory=dict)
    last: dict = field(default_factory=dict)

    def feed(self, f: Feed) -> None:
        """Take the next holes of the log, in order; ValueError when a cell's time goes back."""
        if f is None or not len(f.row):
            return
        for cell in np.unique(f.cell):  # np.unique sorts: cells are independent of each other
            m = f.cell == cell
            t = f.time_s[m]
            rows = f.row[m]
            back = np.flatnonzero(np.diff(t) < 0)
            prev = self.last.get(cell)
            if prev is not None and t[0] < prev[0]:
                raise ValueError(f"{f.where} {f.line(rows[0])}: time {_iso(t[0])} is before the previous hole of cell "
                                 f"'{cell}' ({prev[1]} {prev[2]}, {_iso(prev[0])}): a log must be in time order "
                                 f"within each cell")
            if back.size:
                i = int(back[0])
                raise ValueError(f"{f.where} {f.line(rows[i + 1])}: time {_iso(t[i + 1])} is before the previous hole "
                                 f"of cell '{cell}' ({f.line(rows[i])}, {_iso(t[i])}): a log must be in time order "
                                 f"within each cell")
            self.last[cell] = (float(t[-1]), f.where, f.line(rows[-1]))
            c = m & f.charted
            if len(self.sensors) == 4 and c.any():
                chart = self.charts.setdefault(cell, CusumChart(str(cell), self.sensors, by_panel=self.by_panel))
                import pyarrow as pa

                chart.update(f.hole_id.filter(pa.array(c)), f.time_s[c], f.panel[c], f.rho_mm[c], f.noise_sd_mm[c],
                             f.signature[c])

    def finish(self) -> None:
        """The log has ended: size the alarms still waiting for their new baseline."""
        for ch in self.charts.values():
            ch.finish()

    @property
    def alarms(self) -> list:
        return sorted((a for ch in self.charts.values() for a in ch.alarms), key=lambda a: (a.time_s, a.cell))


@dataclass
class PartResult:
    """One partition measured: its summary, its feed (None when fed batch by batch), its rows."""

    relative: str
    summary: FleetSummary
    feed: Feed | None
    rows: int
    written: bool


def _where(log: HoleLog, part: Partition) -> str:
    return log.display if not log.partitioned else f"{log.display}: partition {part.relative}"


def measure_partition(log: HoleLog, part: Partition, layout: SensorLayout, settings: Settings, sink=None,
                      output=None, watch: Watch | None = None, progress=None) -> PartResult:
    """Measure one partition of ``log``.

    ``sink`` (a :class:`~metrology.io.holeout.TableSink` open for the whole run) or ``output`` (a
    :class:`~metrology.io.holeout.PartitionedOutput`: this partition's own file, skipped when an
    earlier run wrote it) takes the per-hole results. With ``watch`` the drift watch is fed batch by
    batch (bounded memory); without it the partition's :class:`Feed` is returned for the caller
    to feed in log order. ``progress(rows)`` is called after each batch.
    """
    import contextlib

    summary = FleetSummary(float(np.degrees(settings.tolerance)))
    feeds, rows = [], 0
    where = _where(log, part)
    write = output is not None and not output.done(part.relative)
    keys = list(part.keys)  # in the output's folder names, as in the log's: not in its files (a hive dataset)
    with (output.sink(part.relative) if write else contextlib.nullcontext()) as own:
        for table, first in log.batches(part):
            batch = measure_batch(layout, table, settings)
            summary.add(batch)
            f = Feed.of(batch, where, first, csv=log.kind == "csv")
            if watch is not None:
                watch.feed(f)
            else:
                _check_order(f)
                feeds.append(f)
            if own is not None:  # the partition's keys are in its path, as in the log
                own.write(_public(batch.columns, keys))
            elif sink is not None:
                sink.write(_public(batch.columns))
            rows += len(batch)
            if progress is not None:
                progress(len(batch))
    return PartResult(part.relative, summary, None if watch is not None else Feed.concat(feeds), rows,
                      write or sink is not None)


def _public(table, drop=()):
    """The results as written: without the columns metro added for its own use (and ``drop``)."""
    return table.drop_columns([c for c in (*INTERNAL, *drop) if c in table.column_names])


def _check_order(f: Feed) -> None:
    """The time order of each cell within a partition (the watch checks across partitions)."""
    Watch(()).feed(f)


@dataclass
class MeasureResult:
    """A whole log measured.

    Attributes
    ----------
    summary : FleetSummary; watch : Watch; rows : int; partitions : int
    written : int, partitions written by this run (the rest were already there)
    """

    summary: FleetSummary
    watch: Watch
    rows: int
    partitions: int
    written: int

    @property
    def alarms(self) -> list:
        return self.watch.alarms


def measure_log(log: HoleLog, layout: SensorLayout, settings: Settings, sink=None, output=None,
                progress=None, by_panel: bool = False) -> MeasureResult:
    """Measure every partition of ``log`` in one process, in order (see :func:`measure_partition`)."""
    summary = FleetSummary(float(np.degrees(settings.tolerance)))
    watch = Watch(layout.names, by_panel)
    rows = written = 0
    if output is not None:
        output.begin()
    for part in log.partitions:
        r = measure_partition(log, part, layout, settings, sink=sink, output=output, watch=watch, progress=progress)
        summary.merge(r.summary)
        rows += r.rows
        written += r.written
    watch.finish()
    return MeasureResult(summary, watch, rows, len(log.partitions), written)

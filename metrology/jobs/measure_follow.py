"""``metro measure LOG --follow``: a live log, one hole a line; each hole's answer (and any drift
alarm) as soon as its line arrives.

The log is a CSV with its header first (the columns of ``metro measure``'s log), from standard
input (``-``) or a file read to its end. A thread reads the stream's complete lines as they come;
the measuring takes every line already read (at most :data:`MAX_BATCH`) as one batch: read by
:mod:`metrology.io.holelog_csv`'s reader (:func:`metrology.io.loglines.read_lines`), measured by
:func:`metrology.measure.holes.measure_batch` at once (the panel's local surface where
``--panel``/``--points`` or the layout's ``[panel]`` give it), fed to the drift watch, answered in
order. A slow trickle is answered line by line (each line is alone when it is measured); a fast
stream (or a file) goes in batches, which keeps up with thousands of lines a second.

The answers are those of one line at a time, in the same order:

- a hole's answer depends on its own row only; a batch never holds a ``hole_id`` twice (it is cut
  there: ``measure_batch`` would call the second one a duplicate, one line at a time does not);
- a drift alarm is announced right after the hole that raised it, and sized right after the hole
  that completed its new baseline: a batch in which the watch raised or sized an alarm (or that
  holds a line in error) is measured again one line at a time, from the watch as it was before the
  batch (a snapshot of the watch, taken every :data:`SNAPSHOT_ROWS` rows, and the feeds since);
- a line in error stops the run with its one-line error (naming the line) after every line before
  it has been answered.

The first :data:`UNIT_LINES` lines (or fewer, when the stream ends or a line in error comes first)
are held unanswered and checked as ``metro measure`` checks a log's first rows: the readings' unit
(the reach rule, :data:`metrology.jobs.measure.SPOT_REACH`) and, with a hole table, the commanded
positions' (:func:`metrology.jobs.measure_panel.check_units`), by the same functions on the lines
held in memory (:func:`metrology.io.loglines.lines_log`). A log in another unit is refused with
the batch run's one-line message before any hole is answered. A line is held no longer than
:data:`UNIT_WAIT_S` after the first: where the lines come slower (a cell's holes seconds apart), the
lines held are checked as a log of as few rows is (the reach rule needs :data:`UNIT_LINES` holes)
and answered, and the checks run again on the first :data:`UNIT_LINES` lines when they have come,
before that line is answered: a refusal then stops the run after the answers already given.

``on_hole(dict)`` receives each hole's answer, ``on_alarm(dict)`` each alarm as it is raised,
``on_batch()`` (if given) the end of each batch's answers (where the caller flushes).
"""

from __future__ import annotations

import copy
import dataclasses
import queue
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from metrology.jobs.measure import REACH_HOLES

__all__ = ["FollowSummary", "follow_log", "PANEL_COLUMNS", "MAX_BATCH", "SNAPSHOT_ROWS", "UNIT_LINES"]

#: the per-hole columns of a run with the panel known, each in the hole's JSON line as in the table
PANEL_COLUMNS = ("k1_per_mm", "k2_per_mm", "correction_deg", "panel_misfit_per_mm", "panel_misfit_z",
                 "normal_vs_cad_deg", "cad_offset_mm")
#: lines measured together at most: a batch's first hole waits for its last (about 10 ms for 256
#: holes on this machine, benchmarks/results/bench_plant.md), and a batch measured again one line
#: at a time (an alarm in it) costs at most this many single-line measurements
MAX_BATCH = 256
#: batches of lines the reading thread may hold read ahead (a file followed from its start is not read
#: into memory whole: the thread waits while this many batches wait to be measured)
READ_AHEAD = 8
#: rows fed to the drift watch between two snapshots of it (the watch is restored to its snapshot and
#: the feeds since are fed again when a batch is measured again one line at a time)
SNAPSHOT_ROWS = 4096
#: the first lines held and checked for their units before any is answered (module docstring): the reach rule's
#: median needs as many holes; a stream cannot wait for the batch run's 4,096 rows, and one line alone would let one
#: gross reading (a sensor's no-reading code) refuse a run whose unit is right
UNIT_LINES = REACH_HOLES
#: seconds a held line waits for the rest of the first :data:`UNIT_LINES` (module docstring): a cell's holes come
#: seconds apart, and a client that waits for each answer before it sends the next line must get its first answers
UNIT_WAIT_S = 2.0


@dataclass(frozen=True)
class FollowSummary:
    """What a followed log came to: counts by status and the alarms raised (dicts)."""

    counts: dict
    alarms: list
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"counts": dict(self.counts), "alarms": list(self.alarms), "notes": list(self.notes)}


def follow_log(source, layout_path, on_hole, on_alarm=None, options=None, stream=None, on_batch=None,
               max_batch: int = MAX_BATCH) -> FollowSummary:
    """Measure the lines of ``source`` (``-``: ``stream`` or stdin) as they arrive (module docstring).

    ``options`` : :class:`metrology.jobs.measure.MeasureOptions` (its tolerance, radius bound and
    panel fields; checked as ``metro measure`` checks them). Raises ValueError naming the line on a
    line that cannot be measured (a non-number reading, a missing field, time going back); the holes
    before it have been answered."""
    from metrology.io.layout import load_layout
    from metrology.io.names import display_name
    from metrology.jobs.measure import MeasureOptions, _panel_options
    from metrology.jobs.measure_panel import surfaces_and_units
    from metrology.measure.holes import Settings

    o, _ = _panel_options(MeasureOptions() if options is None else options, layout_path)
    layout = load_layout(layout_path)
    if o.panel is not None and o.points is None:
        raise ValueError(f"--panel {display_name(o.panel)}: give the hole table too (--points HOLES.csv)")
    surfaces, check_units = None, None
    if o.points is not None:  # the panel and the table checked now; the log's positions on its first lines
        surfaces, check_units = surfaces_and_units(layout, o.panel, o.points, o.position_error_mm,
                                                   o.form_tolerance_mm, o.spin_deg, o.units)
    settings = Settings(tolerance=float(np.radians(o.tolerance_deg)), min_radius_mm=float(o.min_radius_mm),
                        surfaces=surfaces)
    name = "<stdin>" if str(source) == "-" else str(source)
    fh = (stream or sys.stdin) if str(source) == "-" else open(source, newline="")
    lines, cut = queue.Queue(maxsize=READ_AHEAD * max(int(max_batch), 1)), []
    reader = threading.Thread(target=_read, args=(fh, lines, cut), name="metro-follow-read", daemon=True)
    reader.start()
    run = _Run(layout, settings, name, on_hole, on_alarm, surfaces is not None)
    try:
        first = _take(lines)
        if first is None or not first[1].strip():
            raise ValueError(f"{name}: no header line (hole_id, time, d_<sensor>...)")
        run.start(first[1])
        held, ended, error = _hold(lines, UNIT_LINES, UNIT_WAIT_S)
        run.check(held, check_units, display_name(layout_path))
        unchecked = list(held) if len(held) < UNIT_LINES and not ended and error is None else None
        for i in range(0, len(held), max(int(max_batch), 1)):
            run.batch(held[i:i + max(int(max_batch), 1)])
        if held and on_batch is not None:
            on_batch()
        if error is not None:
            raise error
        while not ended:
            item = _take(lines)
            if item is None:
                break
            batch, error = [item], None
            while len(batch) < max_batch:  # every line already read: one batch
                try:
                    item = lines.get_nowait()
                except queue.Empty:
                    break
                if item is None:
                    ended = True
                    break
                if item[0] is None:  # the reader's error: the lines read before it are answered first
                    error = item[1]
                    break
                batch.append(item)
            batch = [(k, text) for k, text in batch if not _blank(text)]
            if unchecked is not None and batch:  # the held lines' wait ran out: the first UNIT_LINES checked again
                unchecked += batch
                if len(unchecked) >= UNIT_LINES or ended:
                    run.check(unchecked[:UNIT_LINES], check_units, display_name(layout_path))
                    unchecked = None
            if batch:
                run.batch(batch)
                if on_batch is not None:
                    on_batch()
            if error is not None:
                raise error
    finally:
        if fh is not sys.stdin and fh is not stream:
            fh.close()
    reader.join()
    return run.finish([f"{name}: the last line ({cut[0][:40]!r}) ends without a newline: incomplete (cut inside a "
                       f"field?), not measured"] if cut else [])


def _read(fh, lines, cut) -> None:
    """The reading thread: (line number, text) of each complete line into ``lines``, then None. A
    last line without its newline (the stream ended inside it: a writer killed, a cut file) goes to
    ``cut``, not measured: "50.2089" cut to "50.20" would read as a number. (readline: click 8.2's
    test stdin raises EOFError from ``__next__``.)"""
    try:
        for k, line in enumerate(iter(fh.readline, ""), start=1):
            if not line.endswith(("\n", "\r")):
                if line.strip():
                    cut.append(line)
                break
            lines.put((k, line))
    except Exception as exc:  # noqa: BLE001 - raised again in the measuring thread (a decoding error...)
        lines.put((None, exc))
    lines.put(None)


def _hold(lines, n, wait_s):
    """``(held, ended, error)``: the first ``n`` lines that are not blank, read (fewer: the stream ``ended``, the
    reader's ``error`` came first, or ``wait_s`` seconds passed since the first was held)."""
    held, end = [], None
    while len(held) < n:
        try:
            item = lines.get(timeout=None if end is None else max(end - time.monotonic(), 0.0))
        except queue.Empty:
            return held, False, None
        if item is None:
            return held, True, None
        if item[0] is None:
            return held, False, item[1]
        if not _blank(item[1]):
            held.append(item)
            end = time.monotonic() + wait_s if end is None else end
    return held, False, None


def _take(lines):
    return _checked(lines.get())


def _checked(item):
    if item is not None and item[0] is None:
        raise item[1]
    return item


def _blank(text: str) -> bool:
    """A line with no field that holds anything (skipped, as a CSV reader of the whole file would)."""
    return not text.strip().replace(",", "").replace('"', "").strip()


class _Run:
    """The measuring of one followed log: the drift watch, its snapshot, what was answered."""

    def __init__(self, layout, settings, name, on_hole, on_alarm, panel: bool):
        from metrology.io.holelog_csv import CsvLog
        from metrology.measure.holes import Status
        from metrology.measure.run import Watch

        self.layout, self.settings, self.name = layout, settings, name
        self.on_hole, self.on_alarm, self.panel = on_hole, on_alarm, panel
        self.watch = Watch(layout.names)
        self.snapshot, self.since, self.since_rows = copy.deepcopy(self.watch), [], 0
        self.log = CsvLog(name, (), layout.names, display=name)  # how the watch's errors name a line
        self.counts = {str(s): 0 for s in Status}
        self.alarms, self.raised = [], set()
        self.header = ()

    def start(self, line: str) -> None:
        import csv

        from metrology.io.loglines import check_header

        self.header = tuple(h.strip() for h in next(csv.reader([line]), []))
        check_header(self.header, self.layout.names, self.name)

    def check(self, items, check_units, shown_layout) -> None:
        """The first lines held to ``metro measure``'s checks of a log's first rows (module docstring): the commanded
        positions against the table (``check_units(log)``, None: no table), the readings' reach; ValueError, one
        line. The lines before the first that cannot be read are checked (that one stops the run when answered)."""
        from metrology.io.loglines import lines_log, read_lines
        from metrology.jobs.measure import _check_reach

        def readable(part):
            try:
                read_lines(self.header, [t for _, t in part], [k for k, _ in part], self.layout.names, self.name)
            except ValueError:
                return False
            return True

        n = len(items)
        while n and not readable(items[:n]):
            n -= 1
        if not n:
            return
        log = lines_log(self.header, [t for _, t in items[:n]], [k for k, _ in items[:n]], self.layout.names,
                        self.name)
        if check_units is not None:
            check_units(log)
        _check_reach(self.layout, log, shown_layout)

    def batch(self, items) -> None:
        """Measure ``items`` ((line number, text), in order) and answer them (module docstring)."""
        import pyarrow.compute as pc

        from metrology.io.loglines import read_lines

        if len(items) == 1:
            self._one(*items[0])
            return
        try:
            table = read_lines(self.header, [t for _, t in items], [k for k, _ in items], self.layout.names, self.name)
        except ValueError:
            self._each(items)  # the line in error raises after the lines before it are answered
            return
        ids = table.column("hole_id")
        if len(pc.unique(ids)) == len(ids):
            self._measure(items, table)
            return
        lo, seen = 0, set()
        for i, hid in enumerate(ids.to_pylist()):  # cut where an id repeats
            if hid in seen:
                self._measure(items[lo:i], table.slice(lo, i - lo))
                lo, seen = i, set()
            seen.add(hid)
        self._measure(items[lo:], table.slice(lo))

    def _measure(self, items, table) -> None:
        from metrology.measure.holes import measure_batch

        events = self._events()
        try:
            batch = measure_batch(self.layout, table, self.settings)
            feed = self._feed(batch, [k for k, _ in items])
            self.watch.feed(feed)
            again = self._events() != events
        except ValueError:
            again = True
        if again:  # an alarm raised or sized inside the batch, or a line in error: one line at a time
            self._restore()
            self._each(items)
            return
        self._keep(feed)
        for hole in _answers(batch, [k for k, _ in items], self.panel):
            self.counts[hole["status"]] += 1
            self.on_hole(hole)

    def _each(self, items) -> None:
        for k, text in items:
            self._one(k, text)

    def _one(self, k: int, text: str) -> None:
        """One line measured on its own: answered, fed to the watch, its alarms reported."""
        from metrology.io.loglines import read_lines
        from metrology.measure.holes import measure_batch

        try:
            table = read_lines(self.header, [text], [k], self.layout.names, self.name)
        except ValueError:
            import csv

            fields = len(next(csv.reader([text]), []))
            if fields != len(self.header):  # named as a line (pyarrow's parse error names none)
                raise ValueError(f"{self.name}: line {k}: {fields} fields, the header has {len(self.header)}") from None
            raise
        batch = measure_batch(self.layout, table, self.settings)
        hole = next(_answers(batch, [k], self.panel))
        self.counts[hole["status"]] += 1
        self.on_hole(hole)
        feed = self._feed(batch, [k])
        self.watch.feed(feed)
        self._keep(feed)
        self._report()

    def _feed(self, batch, numbers):
        from metrology.measure.run import Feed

        feed = Feed.of(batch, self.log)
        return dataclasses.replace(feed, row=np.asarray(numbers, int) - 2)  # CsvLog: row r is line r + 2

    def _keep(self, feed) -> None:
        """Keep ``feed`` for a replay; a new snapshot of the watch every :data:`SNAPSHOT_ROWS` rows."""
        self.since.append(feed)
        self.since_rows += len(feed.row)
        if self.since_rows >= SNAPSHOT_ROWS:
            self.snapshot, self.since, self.since_rows = copy.deepcopy(self.watch), [], 0

    def _restore(self) -> None:
        """The watch as it was before the batch: its snapshot, fed again what came since."""
        self.watch = copy.deepcopy(self.snapshot)
        for f in self.since:
            self.watch.feed(f)

    def _events(self) -> tuple:
        charts = self.watch.charts.values()
        return (sum(len(ch.alarms) for ch in charts),
                tuple(sorted((p.raised["cell"], p.raised["hole_id"]) for ch in charts if (p := ch.pending) is not None)))

    def _report(self) -> None:
        """Each alarm as it is raised (``{"raised": True, ...}``: the hole and direction, at once) and
        again when sized on its new baseline (the full alarm, as ``metro measure`` reports it)."""
        for ch in self.watch.charts.values():
            p = ch.pending
            if p is not None:
                key = (p.raised["cell"], p.raised["hole_id"])
                if key not in self.raised:
                    self.raised.add(key)
                    if self.on_alarm is not None:
                        self.on_alarm({"raised": True, **p.raised})
        filed = sorted((a for ch in self.watch.charts.values() for a in ch.alarms), key=lambda a: (a.time_s, a.cell))
        for a in filed[len(self.alarms):]:
            self.alarms.append(a.to_dict())
            if self.on_alarm is not None:
                self.on_alarm(a.to_dict())

    def finish(self, notes) -> FollowSummary:
        self.watch.finish()
        self._report()
        return FollowSummary(self.counts, self.alarms, notes)


def _answers(batch, numbers, panel: bool):
    """Each hole's answer (a dict, the JSON line), in order."""
    from metrology.io.holelog_schema import TIME_S
    from metrology.measure.holes import STATUSES

    t = batch.columns
    n = len(numbers)
    names = ("hole_id", "cell", "angle_deg", "U95_angle_deg", "angle_after_deg", "U95_after_deg", "normal_x",
             "normal_y", "normal_z", "reason", *(PANEL_COLUMNS if panel else ()))
    col = {c: t.column(c).to_pylist() if c in t.column_names else [None] * n for c in names}
    times = t.column(TIME_S).to_pylist()
    status = [str(STATUSES[int(s)]) for s in batch.status]
    for i in range(n):
        yield {"line": numbers[i], "hole_id": col["hole_id"][i], "time": _iso(times[i]), "cell": col["cell"][i],
               "status": status[i], "angle_deg": col["angle_deg"][i], "U95_angle_deg": col["U95_angle_deg"][i],
               "angle_after_deg": col["angle_after_deg"][i], "U95_after_deg": col["U95_after_deg"][i],
               "normal": [col["normal_x"][i], col["normal_y"][i], col["normal_z"][i]],
               **({c: col[c][i] for c in PANEL_COLUMNS} if panel else {}), "reason": col["reason"][i]}


def _iso(t_s: float) -> str:
    """ISO 8601 UTC of seconds since 1970, to the microsecond (the results' timestamp)."""
    import datetime as dt

    return dt.datetime.fromtimestamp(float(t_s), dt.timezone.utc).isoformat(timespec="microseconds").replace(
        "+00:00", "Z")

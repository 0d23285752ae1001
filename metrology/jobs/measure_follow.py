"""``metro measure LOG --follow``: a live log, one hole a line; each hole's answer (and any drift
alarm) as soon as its line arrives.

The log is a CSV with its header first (the columns of ``metro measure``'s log), from standard
input (``-``) or a file read to its end. Each complete line is measured on its own
(:func:`metrology.measure.holes.measure_batch` on one row, the panel's local surface where
``--panel``/``--points`` or the layout's ``[panel]`` give it) and fed to the drift watch in order;
``on_hole(dict)`` receives the hole's answer, ``on_alarm(dict)`` each alarm as it is raised.
"""

from __future__ import annotations

import csv
import sys
from dataclasses import dataclass, field

import numpy as np

__all__ = ["FollowSummary", "follow_log", "PANEL_COLUMNS"]

#: the per-hole columns of a run with the panel known, each in the hole's JSON line as in the table
PANEL_COLUMNS = ("k1_per_mm", "k2_per_mm", "correction_deg", "panel_misfit_per_mm", "panel_misfit_z",
                 "normal_vs_cad_deg", "cad_offset_mm")


@dataclass(frozen=True)
class FollowSummary:
    """What a followed log came to: counts by status and the alarms raised (dicts)."""

    counts: dict
    alarms: list
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"counts": dict(self.counts), "alarms": list(self.alarms), "notes": list(self.notes)}


def _value(text):
    try:
        return float(text)
    except ValueError:
        return text


def follow_log(source, layout_path, on_hole, on_alarm=None, tolerance_deg: float = 0.5,
               min_radius_mm: float | None = None, panel=None, points=None, position_error_mm: float = 0.5,
               form_tolerance_mm: float = 0.0, spin_deg: float | None = None, stream=None, units=None) -> FollowSummary:
    """Measure each line of ``source`` (``-``: ``stream`` or stdin) as it arrives (module docstring).

    Raises ValueError naming the line on a line that cannot be measured (a non-number reading, a
    missing column); the holes before it have been answered."""
    import pyarrow as pa

    from metrology.io.holelog import NUMERIC, TIME_S, CsvLog, batch_of
    from metrology.io.layout import load_layout
    from metrology.jobs.measure_panel import hole_surfaces, layout_panel
    from metrology.measure.holes import STATUSES, Settings, Status, measure_batch
    from metrology.measure.run import Feed, Watch

    layout = load_layout(layout_path)
    stated = layout_panel(layout_path)
    if panel is None and points is None:
        panel, points = stated.get("file"), stated.get("points")
    if min_radius_mm is None:
        from metrology.measure.holes import DEFAULT_MIN_RADIUS_MM

        min_radius_mm = stated.get("radius_mm", DEFAULT_MIN_RADIUS_MM)
    if panel is not None and points is None:
        raise ValueError(f"--panel {panel}: give the hole table too (--points HOLES.csv)")
    surfaces = None
    if points is not None:
        surfaces = hole_surfaces(layout, panel, points, position_error_mm, form_tolerance_mm, spin_deg, units)
    settings = Settings(tolerance=float(np.radians(tolerance_deg)), min_radius_mm=float(min_radius_mm),
                        surfaces=surfaces)
    name = "<stdin>" if str(source) == "-" else str(source)
    fh = (stream or sys.stdin) if str(source) == "-" else open(source, newline="")
    watch = Watch(layout.names)
    log = CsvLog(name, (), layout.names, display=name)  # how errors name a line
    counts = {str(s): 0 for s in Status}
    alarms, raised, cut = [], set(), []
    try:
        # line by line to the stream's end (readline: click 8.2's test stdin raises EOFError from __next__)
        reader = csv.reader(_complete_lines(fh, cut))
        header = next(reader, None)
        if not header:
            raise ValueError(f"{name}: no header line (hole_id, time, d_<sensor>...)")
        header = [h.strip() for h in header]
        missing = [c for c in ("hole_id", "time", *(f"d_{s}" for s in layout.names)) if c not in header]
        if missing:
            raise ValueError(f"{name}: line 1: header lacks {', '.join(missing)}")
        for lineno, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise ValueError(f"{name}: line {lineno}: {len(row)} fields, the header has {len(header)}")
            cols = {}
            for h, v in zip(header, row):
                if h.startswith("d_") or h in NUMERIC:
                    try:
                        cols[h] = pa.array([float(v) if v.strip() else np.nan], pa.float64())
                    except ValueError:
                        raise ValueError(f"{name}: line {lineno}: {h} = {v!r} is not a number"
                                         + (" (mm)" if h.startswith("d_") else "")) from None
                elif h == "time":
                    t = _value(v)
                    cols[h] = pa.array([t], pa.float64() if isinstance(t, float) else pa.string())
                else:
                    cols[h] = pa.array([v], pa.string())
            try:
                table = batch_of(pa.table(cols), layout.names, name)
            except ValueError as exc:
                raise ValueError(f"{name}: line {lineno}: {exc}") from None
            batch = measure_batch(layout, table, settings)
            t = batch.columns
            status = str(STATUSES[int(batch.status[0])])
            counts[status] += 1

            def f(col):
                return t.column(col)[0].as_py() if col in t.column_names else None

            on_hole({"line": lineno, "hole_id": f("hole_id"), "time": _iso(t.column(TIME_S)[0].as_py()),
                     "cell": f("cell"), "status": status, "angle_deg": f("angle_deg"),
                     "U95_angle_deg": f("U95_angle_deg"), "angle_after_deg": f("angle_after_deg"),
                     "U95_after_deg": f("U95_after_deg"),
                     "normal": [f("normal_x"), f("normal_y"), f("normal_z")],
                     **({c: f(c) for c in PANEL_COLUMNS} if surfaces is not None else {}),
                     "reason": f("reason"), **({"cell": f("cell")} if "cell" in t.column_names else {})})
            watch.feed(Feed.of(batch, log, first_row=lineno - 2))
            _report_alarms(watch, alarms, raised, on_alarm)
    finally:
        if fh is not sys.stdin and fh is not stream:
            fh.close()
    watch.finish()
    _report_alarms(watch, alarms, raised, on_alarm)
    notes = [f"{name}: the last line ({cut[0][:40]!r}) ends without a newline: incomplete (cut inside a field?), "
             f"not measured"] if cut else []
    return FollowSummary(counts, alarms, notes)


def _iso(t_s: float) -> str:
    """ISO 8601 UTC of seconds since 1970, to the microsecond (the results' timestamp)."""
    import datetime as dt

    return dt.datetime.fromtimestamp(float(t_s), dt.timezone.utc).isoformat(timespec="microseconds").replace(
        "+00:00", "Z")


def _complete_lines(fh, cut):
    """The stream's lines that end with their newline; a last line without one (the stream ended inside
    it: a writer killed, a cut file) goes to ``cut``, not measured: "50.2089" cut to "50.20" would read
    as a number."""
    for line in iter(fh.readline, ""):
        if not line.endswith(("\n", "\r")):
            if line.strip():
                cut.append(line)
            return
        yield line


def _report_alarms(watch, alarms, raised, on_alarm) -> None:
    """Each alarm as it is raised (``{"raised": True, ...}``: the hole and direction, at once) and
    again when sized on its new baseline (the full alarm, as ``metro measure`` reports it)."""
    for ch in watch.charts.values():
        p = ch.pending
        if p is not None:
            key = (p.raised["cell"], p.raised["hole_id"])
            if key not in raised:
                raised.add(key)
                if on_alarm is not None:
                    on_alarm({"raised": True, **p.raised})
    filed = sorted((a for ch in watch.charts.values() for a in ch.alarms), key=lambda a: (a.time_s, a.cell))
    for a in filed[len(alarms):]:
        alarms.append(a.to_dict())
        if on_alarm is not None:
            on_alarm(a.to_dict())

"""A CAD/CAM hole table for the hole-log simulator: ``hole_id,x,y,z,i,j,k`` (CSV or Parquet).

``x, y, z`` the nominal drill point (mm, panel frame), ``i, j, k`` the drill's feed direction into
the panel (a unit vector within :data:`FEED_UNIT_TOL`, normalised here; another length, a zero or a
non-finite vector is refused). Read on its own (the
simulator does not borrow :mod:`metrology.panel.points`), then checked against the CAD panel
(:func:`check_table`): every point within :data:`ON_PANEL_MM` of the panel along its feed, every
feed entering the panel (``feed . n < 0``), a table spanning more than :data:`MIN_SPAN_MM` (one
that spans less is in metres). Every error is one line naming the file, the row (1 = the first
line after the header) and the value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["HoleTable", "read_hole_table", "check_table", "COLUMNS", "ON_PANEL_MM", "MIN_SPAN_MM", "FEED_UNIT_TOL"]

COLUMNS = ("hole_id", "x", "y", "z", "i", "j", "k")
#: a table point farther than this from the CAD panel along its feed is off the panel (mm)
ON_PANEL_MM = 0.5
#: a table of 2+ holes spanning less than this (bounding-box diagonal, mm) is not in mm
MIN_SPAN_MM = 1.0
#: a feed i,j,k is a unit vector to this (CAM writes 6+ digits; the table's contract, which metro measure holds it to)
FEED_UNIT_TOL = 1e-3
#: how far before the point the feed's ray starts when a point is checked on the panel (mm)
_LEAD_MM = 50.0


@dataclass(frozen=True)
class HoleTable:
    """A hole table.

    Attributes
    ----------
    source : str, the file
    ids : tuple of str, length m, unique
    points : (m, 3) float, mm, panel frame, the nominal drill points
    feed : (m, 3) float, unit, panel frame, the drill's feed direction (into the panel)
    """

    source: str
    ids: tuple
    points: np.ndarray
    feed: np.ndarray

    @property
    def m(self) -> int:
        return len(self.ids)


def _rows(path):
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{path}: no such hole table")
    if p.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(str(p))
        except Exception as exc:
            raise ValueError(f"{path}: cannot read Parquet ({type(exc).__name__})") from None
        names = [c.lower() for c in table.column_names]
        cols = [table.column(i).to_pylist() for i in range(table.num_columns)]
        return names, [[("" if v is None else str(v)) for v in row] for row in zip(*cols)]
    import csv

    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:
            rows = [r for r in csv.reader(fh) if r and not (len(r) == 1 and not r[0].strip())
                    and not r[0].lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a UTF-8 text CSV") from None
    if not rows:
        raise ValueError(f"{path}: empty hole table (expected the header {','.join(COLUMNS)})")
    return [c.strip().lower() for c in rows[0]], rows[1:]


def read_hole_table(path) -> HoleTable:
    """Read and check a hole table on its own (module docstring). ValueError: one line, file, row, value."""
    path = str(path)
    names, rows = _rows(path)
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        raise ValueError(f"{path}: header {','.join(names)}: missing column(s) {','.join(missing)} "
                         f"(expected {','.join(COLUMNS)})")
    col = [names.index(c) for c in COLUMNS]
    if not rows:
        raise ValueError(f"{path}: no holes in the table")
    ids, vals, seen = [], [], {}
    for r, row in enumerate(rows, start=1):
        if len(row) != len(names):
            raise ValueError(f"{path}: row {r}: {len(row)} values, expected {len(names)} ({','.join(names)})")
        hid = row[col[0]].strip()
        if not hid:
            raise ValueError(f"{path}: row {r}: missing hole_id")
        if hid in seen:
            raise ValueError(f"{path}: row {r}: duplicate hole_id {hid!r} (first at row {seen[hid]})")
        seen[hid] = r
        v = []
        for name, c in zip(COLUMNS[1:], col[1:]):
            text = row[c].strip()
            try:
                x = float(text)
            except ValueError:
                raise ValueError(f"{path}: row {r}: hole {hid}: {name} {text!r} is not a number") from None
            if not math.isfinite(x):
                raise ValueError(f"{path}: row {r}: hole {hid}: {name} {text!r} is not finite")
            v.append(x)
        f = np.array(v[3:])
        norm = float(np.linalg.norm(f))
        if norm == 0:
            raise ValueError(f"{path}: row {r}: hole {hid}: feed direction i,j,k is the zero vector")
        if abs(norm - 1.0) > FEED_UNIT_TOL:  # a column out of place, not a scale: as metro measure refuses it
            raise ValueError(f"{path}: row {r}: hole {hid}: feed direction i,j,k has length {norm:.6g}, expected a "
                             f"unit vector (within {FEED_UNIT_TOL:g})")
        ids.append(hid)
        vals.append(v[:3] + list(f / norm))
    a = np.array(vals, float)
    table = HoleTable(path, tuple(ids), a[:, :3], a[:, 3:])
    span = float(np.linalg.norm(np.ptp(table.points, axis=0)))
    if table.m >= 2 and span < MIN_SPAN_MM:
        raise ValueError(f"{path}: the holes span {span:.3g} mm: expected mm (is the table in metres?)")
    return table


def check_table(table: HoleTable, cad, cad_name: str = "the panel") -> None:
    """ValueError naming the file, row and value of the first hole off the CAD panel ``cad`` (a
    :class:`~metrology.sim.forward.panels.Panel`), or whose feed does not enter it."""
    start = table.points - _LEAD_MM * table.feed
    t = cad.intersect(start, table.feed)
    gap = np.abs(t - _LEAD_MM)
    bad = np.flatnonzero(~(gap <= ON_PANEL_MM))
    n = cad.normal_at(np.where(np.isfinite(t)[:, None], start + t[:, None] * table.feed, table.points))
    into = np.sum(n * table.feed, axis=1)
    bad = set(bad.tolist())
    for r in range(table.m):
        p, f = table.points[r], table.feed[r]
        where = f"{table.source}: row {r + 1}: hole {table.ids[r]}"
        if np.isfinite(into[r]) and into[r] >= 0:
            raise ValueError(f"{where}: feed ({f[0]:.4g}, {f[1]:.4g}, {f[2]:.4g}) points out of {cad_name} "
                             f"(its outward normal there is ({n[r, 0]:.4g}, {n[r, 1]:.4g}, {n[r, 2]:.4g}))")
        if r in bad:
            what = "misses it" if not np.isfinite(t[r]) else f"is {gap[r]:.3g} mm from it along the feed"
            raise ValueError(f"{where}: point ({p[0]:.6g}, {p[1]:.6g}, {p[2]:.6g}) mm is off {cad_name} (it {what}; "
                             f"expected within {ON_PANEL_MM:g} mm; is the table in mm and in the panel's frame?)")

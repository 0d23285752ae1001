"""The tracker export: one CSV row per pose (a public contract, see README "File formats").

Columns ``pose_id,time_s,temp_c,x,y,z,qw,qx,qy,qz,d_L1,d_L2,...``: ``(x, y, z)`` mm and the
unit quaternion ``(qw, qx, qy, qz)`` (scalar first) give the TCS in the tracker frame,
``p_tracker = R(q) p_tcs + (x, y, z)``. ``d_<name>`` is the reading of sensor ``<name>`` in mm;
an empty cell is no reading (out of range), which drops that reading, not the pose.
``time_s`` and ``temp_c`` are optional columns.

Two common export settings are read on request (:func:`read_export`): quaternions written
scalar-last under the same header (``quaternion_order="xyzw"``: the columns ``qw, qx, qy, qz``
hold ``x, y, z, w``) and positions in metres or inches (``position_units``).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, replace

import numpy as np

from metrology.io.atomic import write_text
from metrology.core.tolerances import QUATERNION_NORM

__all__ = ["TrackerExport", "read_export", "export_from_rows", "write_export", "export_to_csv", "read_csv_rows",
           "QUATERNION_ORDERS", "POSITION_UNITS"]

#: what the four columns ``qw, qx, qy, qz`` hold -> the column indices of (w, x, y, z)
QUATERNION_ORDERS = {"wxyz": [0, 1, 2, 3], "xyzw": [3, 0, 1, 2]}

#: unit of the position columns ``x, y, z`` -> mm per unit
POSITION_UNITS = {"mm": 1.0, "m": 1000.0, "in": 25.4}

REQUIRED = ("pose_id", "x", "y", "z", "qw", "qx", "qy", "qz")
OPTIONAL = ("time_s", "temp_c")


@dataclass(frozen=True)
class TrackerExport:
    """Poses and readings of one calibration or validation run.

    Attributes
    ----------
    pose_id : (p,) str
    time_s : (p,) float, s; NaN where the column is absent
    temp_c : (p,) float, deg C; NaN where the column is absent
    quaternion : (p, 4) float, unit, scalar first, tcs2tracker rotation
    tcs2tracker_trans : (p, 3) float, mm, tracker frame
    names : tuple of str, length n, the sensors in column order
    d : (p, n) float, mm; NaN = no reading
    """

    pose_id: tuple
    time_s: np.ndarray
    temp_c: np.ndarray
    quaternion: np.ndarray
    tcs2tracker_trans: np.ndarray
    names: tuple
    d: np.ndarray

    @property
    def n_poses(self) -> int:
        return len(self.pose_id)

    @property
    def tcs2tracker_rot(self) -> np.ndarray:
        """(p, 3, 3) float rotation matrices from the quaternions."""
        from metrology.core.frames import matrix_from_quaternion

        return matrix_from_quaternion(self.quaternion)

    def select(self, idx) -> "TrackerExport":
        """The poses ``idx`` (index array or boolean mask) as a new export."""
        idx = np.asarray(idx)
        return replace(
            self, pose_id=tuple(np.asarray(self.pose_id, dtype=object)[idx]), time_s=self.time_s[idx],
            temp_c=self.temp_c[idx], quaternion=self.quaternion[idx],
            tcs2tracker_trans=self.tcs2tracker_trans[idx], d=self.d[idx],
        )

    def reordered(self, names) -> "TrackerExport":
        """Columns reordered to ``names`` (which must be exactly this export's sensors)."""
        if sorted(names) != sorted(self.names):
            raise ValueError(f"sensors differ: export has {list(self.names)}, expected {list(names)}")
        idx = [self.names.index(n) for n in names]
        return replace(self, names=tuple(names), d=self.d[:, idx])


def _float(path, line, column, text, allow_empty=False):
    text = text.strip()
    if text == "":
        if allow_empty:
            return math.nan
        raise ValueError(f"{path}: line {line}: column '{column}' is empty")
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{path}: line {line}: column '{column}' = {text!r} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{path}: line {line}: column '{column}' = {text!r} is not finite")
    return value


def read_csv_rows(path, what: str) -> list:
    """All rows of a UTF-8 CSV file (a BOM is accepted); a one-line ValueError naming the
    file when it cannot be read as text. ``what`` names the file's role in the error."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            return list(csv.reader(fh))
    except OSError as exc:
        raise ValueError(f"{path}: cannot read {what} ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a UTF-8 text CSV") from None


def read_export(path, quaternion_order: str = "wxyz", position_units: str = "mm") -> TrackerExport:
    """Read a tracker export CSV; every error names the file, line and column.

    Parameters
    ----------
    path : str or Path
    quaternion_order : {"wxyz", "xyzw"}
        What the columns ``qw, qx, qy, qz`` hold, in that column order: ``"xyzw"`` reads a
        scalar-last export written under the scalar-first header.
    position_units : {"mm", "m", "in"}
        Unit of ``x, y, z``; converted to mm.
    """
    if quaternion_order not in QUATERNION_ORDERS or position_units not in POSITION_UNITS:
        return export_from_rows([], path, quaternion_order, position_units)  # the one-line error
    return export_from_rows(read_csv_rows(path, "export"), path, quaternion_order, position_units)


def export_from_rows(rows, path, quaternion_order: str = "wxyz", position_units: str = "mm",
                     first_line: int = 2) -> TrackerExport:
    """An export from CSV rows (header first, then pose rows), as :func:`read_export` reads it.

    ``path`` names the source in errors and ``first_line`` is the line number of ``rows[1]``
    there (a stream read row by row, ``metro calibrate --follow``, passes its own count).
    """
    if quaternion_order not in QUATERNION_ORDERS:
        raise ValueError(f"quaternion order {quaternion_order!r}: expected one of {', '.join(QUATERNION_ORDERS)}")
    if position_units not in POSITION_UNITS:
        raise ValueError(f"position units {position_units!r}: expected one of {', '.join(POSITION_UNITS)}")
    qidx, scale = QUATERNION_ORDERS[quaternion_order], POSITION_UNITS[position_units]
    rows = [r for r in rows if any(c.strip() for c in r)]
    if not rows:
        raise ValueError(f"{path}: empty file, expected a header line {','.join(REQUIRED)},d_<sensor>,...")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise ValueError(f"{path}: line 1: missing column(s) {', '.join(missing)}")
    if len(set(header)) != len(header):
        raise ValueError(f"{path}: line 1: duplicate column names")
    names = tuple(h[2:] for h in header if h.startswith("d_"))
    if not names:
        raise ValueError(f"{path}: line 1: no reading columns d_<sensor>")
    unknown = [h for h in header if h not in REQUIRED + OPTIONAL and not h.startswith("d_")]
    if unknown:
        raise ValueError(f"{path}: line 1: unknown column(s) {', '.join(unknown)}")
    col = {h: i for i, h in enumerate(header)}
    pose_id, t, temp, quat, trans, d = [], [], [], [], [], []
    for k, row in enumerate(rows[1:], start=first_line):
        if len(row) != len(header):
            raise ValueError(f"{path}: line {k}: {len(row)} fields, header has {len(header)}")
        pose_id.append(row[col["pose_id"]].strip())
        t.append(_float(path, k, "time_s", row[col["time_s"]], True) if "time_s" in col else math.nan)
        temp.append(_float(path, k, "temp_c", row[col["temp_c"]], True) if "temp_c" in col else math.nan)
        trans.append([scale * _float(path, k, c, row[col[c]]) for c in ("x", "y", "z")])
        q = np.array([_float(path, k, c, row[col[c]]) for c in ("qw", "qx", "qy", "qz")])[qidx]
        qn = np.linalg.norm(q)
        if abs(qn - 1.0) > QUATERNION_NORM:
            raise ValueError(f"{path}: line {k}: quaternion norm {qn:.6f}, expected 1 within {QUATERNION_NORM}")
        quat.append(q / qn)
        d.append([_float(path, k, "d_" + n, row[col["d_" + n]], True) for n in names])
    if not pose_id:
        raise ValueError(f"{path}: no pose rows after the header")
    if len(set(pose_id)) != len(pose_id):
        raise ValueError(f"{path}: duplicate pose_id values")
    return TrackerExport(tuple(pose_id), np.array(t), np.array(temp), np.array(quat), np.array(trans), names, np.array(d))


def export_to_csv(export: TrackerExport) -> str:
    """CSV text of an export (full precision: 9 decimals in mm, 12 in the quaternion)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    has_t = np.any(np.isfinite(export.time_s))
    has_temp = np.any(np.isfinite(export.temp_c))
    header = ["pose_id"] + (["time_s"] if has_t else []) + (["temp_c"] if has_temp else [])
    header += ["x", "y", "z", "qw", "qx", "qy", "qz"] + ["d_" + n for n in export.names]
    w.writerow(header)
    fmt = lambda v, p: "" if not np.isfinite(v) else f"{v:.{p}f}"  # noqa: E731
    for i in range(export.n_poses):
        row = [export.pose_id[i]]
        if has_t:
            row.append(fmt(export.time_s[i], 3))
        if has_temp:
            row.append(fmt(export.temp_c[i], 3))
        row += [fmt(v, 9) for v in export.tcs2tracker_trans[i]] + [fmt(v, 12) for v in export.quaternion[i]]
        row += [fmt(v, 9) for v in export.d[i]]
        w.writerow(row)
    return buf.getvalue()


def write_export(export: TrackerExport, path) -> None:
    """Write ``export`` as CSV to ``path`` atomically."""
    write_text(path, export_to_csv(export))

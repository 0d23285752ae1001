"""Hole logs to files, as a cell writes them, with the truth apart.

The log (one row per hole, a cell's columns only)::

    hole_id, time, cell, panel, temperature_c, d_<sensor>..., d_<sensor>_after...,
    pose_rx_deg, pose_ry_deg, pose_rz_deg, pose_x_mm, pose_y_mm, pose_z_mm

``hole_id`` is ``"<cell>-<8 digits>"`` (unique in the fleet), ``time`` s since the Unix epoch (UTC,
to the ms), ``panel`` ``"P<6 digits>"`` (the cell's panel count), readings in mm, blank (null) where
the sensor gave none. ``pose_*`` is the robot's commanded pose before the adjustment, known to a
real cell: ``pose_r{x,y,z}_deg`` the ``tcs2panel`` rotation (TCS to panel frame) as a rotation
vector (axis times angle, degrees; ``scipy.spatial.transform.Rotation.from_rotvec(...,
degrees=True)`` reads it), ``pose_{x,y,z}_mm`` the TCS origin in the panel frame (mm). A vector
``v_tcs`` is ``R v_tcs`` in the panel frame; a point ``p_tcs`` is ``R p_tcs + pose_xyz``.

Drilled from a hole table (``--points``), ``hole_id`` is the table's ``hole_id``; when the table is
drilled more than once (``--holes`` beyond its rows, cycled), pass ``k >= 2`` is logged as
``<hole_id>#<k>`` and ``panel`` is ``P<k, 6 digits>``: each pass over the table is one panel; the
column ``point_id`` (after the readings) holds the table's own ``hole_id`` of every row, the key
to join the log to the table on every pass.

The truth, keyed by ``hole_id``::

    hole_id, cell, drill_x_mm, drill_y_mm, drill_z_mm (panel frame; the point drilled),
    true_angle_deg, true_after_deg, true_normal_{x,y,z}, true_normal_after_{x,y,z} (TCS, unit,
    pointing toward the head), adjusted, offset_<sensor> (mm), gross_<sensor>, gross_<sensor>_after

and from a hole table also ``nominal_{x,y,z}_mm`` (the table's point), ``cad_angle_deg`` (the true
normal at the drilled point against the CAD's at the nominal point) and ``cad_offset_mm`` (the true
surface over the CAD's at the nominal point, along the CAD's outward normal): a panel off its CAD
shows there.

Formats: one CSV or Parquet file (all cells, cell after cell; a Parquet file's row groups are
the simulator's chunks), or a hive-partitioned Parquet folder ``cell=C1/date=2026-11-25/part-<k>.parquet``
(``date`` the UTC date of ``time``; ``k`` counts the files of that partition). A folder is a hive
dataset: its keys are in the folder names only, not in the files (a key in both is a conflict for
pyarrow.dataset, pandas and Dask), so any of them reads the folder as one table.
The truth is one CSV or Parquet file. Every file is written to a temporary beside it and moved
into place when complete (:func:`metrology.io.atomic.atomic_path`). pyarrow is imported inside
the functions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metrology.io.atomic import atomic_path

__all__ = ["log_table", "truth_table", "write_log_csv", "write_log_parquet", "check_log_output", "LOG_FORMATS"]

SECONDS_PER_DAY = 86400


def _ids(prefix: str, number, width: int):
    import pyarrow as pa
    import pyarrow.compute as pc

    text = pc.utf8_lpad(pc.cast(pa.array(np.asarray(number, np.int64)), pa.string()), width, "0")
    return pc.binary_join_element_wise(prefix, text, "")


def _floats(values):
    import pyarrow as pa

    return pa.array(np.asarray(values, float), type=pa.float64(), from_pandas=True)  # NaN -> null (blank)


def log_table(chunk):
    """The cell's log of ``chunk`` (a :class:`HoleChunk`) as a pyarrow Table (module docstring)."""
    import pyarrow as pa

    cols = {"hole_id": _hole_ids(chunk), "time": _floats(chunk.time_s),
            "cell": pa.array(np.full(chunk.n, chunk.cell)), "panel": _ids("P", chunk.panel + 1, 6),
            "temperature_c": _floats(np.round(chunk.temperature_c, 2))}
    for i, name in enumerate(chunk.sensors):
        cols[f"d_{name}"] = _floats(chunk.d[:, i])
    for i, name in enumerate(chunk.sensors):
        cols[f"d_{name}_after"] = _floats(chunk.d_after[:, i])
    if chunk.point_ids is not None:
        cols["point_id"] = pa.array(np.asarray(chunk.point_ids, dtype=object), type=pa.string())
    if chunk.pose_rotvec is not None:
        for j, axis in enumerate("xyz"):
            cols[f"pose_r{axis}_deg"] = _floats(np.degrees(chunk.pose_rotvec[:, j]))
        for j, axis in enumerate("xyz"):
            cols[f"pose_{axis}_mm"] = _floats(chunk.pose_origin[:, j])
    return pa.table(cols)


def _hole_ids(chunk):
    import pyarrow as pa

    if chunk.ids is not None:
        return pa.array(np.asarray(chunk.ids, dtype=object), type=pa.string())
    return _ids(f"{chunk.cell}-", chunk.hole + 1, 8)


def truth_table(chunk):
    """The truth of ``chunk`` as a pyarrow Table, keyed by ``hole_id`` (module docstring)."""
    import pyarrow as pa

    cols = {"hole_id": _hole_ids(chunk), "cell": pa.array(np.full(chunk.n, chunk.cell))}
    for j, axis in enumerate("xyz"):
        cols[f"drill_{axis}_mm"] = _floats(chunk.drill_point[:, j])
    cols["true_angle_deg"] = _floats(np.degrees(chunk.true_angle))
    cols["true_after_deg"] = _floats(np.degrees(chunk.true_after))
    for j, axis in enumerate("xyz"):
        cols[f"true_normal_{axis}"] = _floats(chunk.normal_tcs[:, j])
    for j, axis in enumerate("xyz"):
        cols[f"true_normal_after_{axis}"] = _floats(chunk.normal_after_tcs[:, j])
    cols["adjusted"] = pa.array(chunk.adjusted)
    for i, name in enumerate(chunk.sensors):
        cols[f"offset_{name}"] = _floats(chunk.offset[:, i])
    for i, name in enumerate(chunk.sensors):
        cols[f"gross_{name}"] = pa.array(chunk.gross[:, i])
        cols[f"gross_{name}_after"] = pa.array(chunk.gross_after[:, i])
    if chunk.ids is not None:  # drilled from a hole table
        for j, axis in enumerate("xyz"):
            cols[f"nominal_{axis}_mm"] = _floats(chunk.nominal[:, j])
        cols["cad_angle_deg"] = _floats(np.degrees(chunk.cad_angle))
        cols["cad_offset_mm"] = _floats(chunk.cad_offset)
    return pa.table(cols)


class _CsvSink:
    def __init__(self, path):
        self.path = path

    def open(self, tmp, schema):
        import pyarrow.csv as pcsv

        return pcsv.CSVWriter(str(tmp), schema)


class _ParquetSink:
    def __init__(self, path):
        self.path = path

    def open(self, tmp, schema):
        import pyarrow.parquet as pq

        return pq.ParquetWriter(str(tmp), schema)


#: truth writers by suffix
_TRUTH_SINKS = {".csv": _CsvSink, ".parquet": _ParquetSink}


class _Streamed:
    """One file written chunk by chunk (``table_of(chunk)``) into a temporary, moved into place on close."""

    def __init__(self, path, sink_cls, table_of):
        self.sink = sink_cls(path)
        self.path = Path(path)
        self.table_of = table_of
        self._ctx = None
        self._writer = None

    def write(self, chunk):
        table = self.table_of(chunk)
        if self._writer is None:
            self._ctx = atomic_path(self.path)
            self._writer = self.sink.open(self._ctx.__enter__(), table.schema)
        self._writer.write_table(table)

    def close(self, ok: bool):
        if self._writer is None:
            return
        self._writer.close()
        if ok:
            self._ctx.__exit__(None, None, None)
        else:  # the temporary is removed; nothing half-written is left at the path
            self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)


def _stream(chunks, writers):
    """Feed each chunk to every writer (``write(chunk)``, ``close(ok)``); returns the holes written."""
    n = 0
    ok = False
    try:
        for chunk in chunks:
            for w in writers:
                w.write(chunk)
            n += chunk.n
        ok = True
    finally:
        for w in writers:
            w.close(ok)
    return n


def _truth_writer(truth_path):
    if truth_path is None:
        return []
    return [_Streamed(truth_path, _TRUTH_SINKS[Path(truth_path).suffix.lower()], truth_table)]


def write_log_csv(chunks, path, truth_path=None) -> int:
    """Write the holes of ``chunks`` (an iterable of :class:`HoleChunk`) as one CSV log at ``path``
    and their truth at ``truth_path`` (``.csv`` or ``.parquet``; None: no truth). Returns the holes."""
    return _stream(chunks, [_Streamed(path, _CsvSink, log_table), *_truth_writer(truth_path)])


def _date(day: int) -> str:
    return str(np.datetime64(int(day), "D"))


class _Partitions:
    """Writes each chunk's holes into ``cell=<cell>/date=<UTC date>/part-<k>.parquet``, one file per
    chunk and partition, each atomically."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.count = {}
        self.files = []

    def close(self, ok: bool):
        pass  # every file is already complete

    def write(self, chunk):
        import pyarrow.parquet as pq

        day = np.floor(chunk.time_s / SECONDS_PER_DAY).astype(np.int64)
        cuts = np.flatnonzero(np.diff(day)) + 1  # time increases within a cell: each day is one run
        table = log_table(chunk)
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, chunk.n]):
            part = self.folder / f"cell={chunk.cell}" / f"date={_date(day[lo])}"
            part.mkdir(parents=True, exist_ok=True)
            k = self.count.get(part, 0)
            self.count[part] = k + 1
            target = part / f"part-{k}.parquet"
            with atomic_path(target) as tmp:  # the key cell is the folder's name: not a column of the file
                pq.write_table(table.slice(lo, hi - lo).drop_columns(["cell"]), str(tmp))
            self.files.append(target)


def write_log_parquet_file(chunks, path, truth_path=None) -> int:
    """Write the holes of ``chunks`` as one Parquet log at ``path`` (a row group per chunk) and their
    truth at ``truth_path``. Returns the holes."""
    return _stream(chunks, [_Streamed(path, _ParquetSink, log_table), *_truth_writer(truth_path)])


def write_log_parquet(chunks, folder, truth_path=None) -> tuple:
    """Write the holes of ``chunks`` as a hive-partitioned Parquet log under ``folder`` (created; it
    must be empty or absent) and their truth at ``truth_path``. Returns (holes, files written)."""
    parts = _Partitions(folder)
    n = _stream(chunks, [parts, *_truth_writer(truth_path)])
    return n, parts.files


#: log writers by output kind: ``"csv"``, ``"parquet-file"`` a file, ``"parquet"`` a partitioned folder
LOG_FORMATS = {"csv": write_log_csv, "parquet-file": write_log_parquet_file, "parquet": write_log_parquet}
#: the suffixes of a log written as one file, and its kind
FILE_KINDS = {".csv": "csv", ".parquet": "parquet-file"}


def check_log_output(out, truth=None) -> str:
    """The format of the output ``out`` (``"csv"`` for a ``.csv`` path, ``"parquet-file"`` for a
    ``.parquet`` path, ``"parquet"`` for a folder: any other name, ``out.one`` too), checked before
    any work: ValueError naming the value when it cannot be written."""
    p = Path(str(out))
    if p.suffix.lower() in FILE_KINDS and not str(out).endswith(("/", "\\")):
        if p.is_dir():
            raise ValueError(f"--out {out}: is a folder, expected a {p.suffix} file or a new folder for Parquet")
        if not p.resolve().parent.is_dir():
            raise ValueError(f"--out {out}: folder {p.parent} does not exist")
        kind = FILE_KINDS[p.suffix.lower()]
    else:
        if p.exists() and (not p.is_dir() or any(p.iterdir())):
            raise ValueError(f"--out {out}: exists and is not an empty folder (a log is never written over another)")
        if not p.resolve().parent.is_dir():
            raise ValueError(f"--out {out}: folder {p.parent} does not exist")
        kind = "parquet"
    if truth is not None:
        t = Path(str(truth))
        if t.suffix.lower() not in _TRUTH_SINKS:
            raise ValueError(f"--truth {truth}: expected a .csv or .parquet file")
        if t.resolve() == p.resolve() or (kind == "parquet" and p.resolve() in t.resolve().parents):
            raise ValueError(f"--truth {truth}: must lie apart from the log {out}")
        if t.is_dir() or not t.resolve().parent.is_dir():
            raise ValueError(f"--truth {truth}: not a file in an existing folder")
    return kind


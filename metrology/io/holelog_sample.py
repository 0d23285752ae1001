"""The first rows of a hole log's commanded positions, read alone (of its files, or of the lines ``--follow`` holds
first): what the units rule (:func:`metrology.io.panel_units.check_panel_units`) holds against the hole table before
any hole is measured; and of its readings (:func:`first_readings`), what ``metro measure``'s reach rule holds
against the head.

Only the join's key (``point_id`` where the log has it, else ``hole_id``) and ``pose_x_mm``, ``pose_y_mm``,
``pose_z_mm`` are read, from the first partitions, at most :data:`SAMPLE_ROWS` rows: a median over a few
thousand holes names a unit as well as one over 400 k, and costs a few milliseconds whatever the log's size.
"""

from __future__ import annotations

import numpy as np

from metrology.io.arrays import to_numpy
from metrology.io.holelog_csv import CsvLog
from metrology.io.holelog_schema import POSE_POSITION, table_key

__all__ = ["commanded_positions", "first_readings", "SAMPLE_ROWS"]

#: rows read at most (the rule takes a median: a few thousand holes settle it)
SAMPLE_ROWS = 4096


def commanded_positions(log, rows: int = SAMPLE_ROWS):
    """``(keys (m,) str, positions (m, 3) float, as written (mm by the columns' names), panel frame)`` of the
    first ``rows`` rows of ``log`` (a :class:`metrology.io.holelog_reader.HoleLog`) that carry the columns; None when
    the log has no ``pose_x_mm`` .. ``pose_z_mm``. A value that is not a number reads NaN (the reader names it)."""
    keys, xyz, left = [], [], rows
    for part in log.partitions:
        names = log.file_columns(part)
        if not all(c in names for c in POSE_POSITION):
            continue
        for k, p in _read(log, part, table_key(names), left):
            keys.append(k)
            xyz.append(p)
            left -= len(k)
        if left <= 0:
            break
    if not keys:
        return None
    return np.concatenate(keys), np.concatenate(xyz)


def first_readings(log, columns, rows: int = SAMPLE_ROWS):
    """The first ``rows`` rows of ``log``'s reading ``columns`` (``d_<sensor>``), ``(m, len(columns))`` float, as
    written (mm by the log's contract; blank or not a number: NaN); None when no partition has them all."""
    out, left = [], rows
    for part in log.partitions:
        if not all(c in log.file_columns(part) for c in columns):
            continue
        for _, d in _read(log, part, None, left, tuple(columns)):
            out.append(d)
            left -= len(d)
        if left <= 0:
            break
    return np.concatenate(out) if out else None


def _read(log, part, key, rows, numeric=POSE_POSITION):
    """``(keys, numbers)`` chunks of ``part``'s first ``rows`` rows (its ``key`` and ``numeric`` columns alone; no
    key: None for the keys), read as the log's reader reads the partition (a CSV file, or lines in memory:
    ``CsvLog.readable``; else Parquet)."""
    import pyarrow as pa

    columns = [*([key] if key else []), *numeric]
    if isinstance(log, CsvLog):
        import pyarrow.csv as pcsv

        types = {c: pa.string() for c in columns}
        try:
            reader = pcsv.open_csv(log.readable(part), read_options=pcsv.ReadOptions(block_size=1 << 20),
                                   convert_options=pcsv.ConvertOptions(include_columns=columns, column_types=types))
        except (pa.ArrowInvalid, OSError):
            return  # the log's reader names what is wrong with the file
        batches = reader
    else:
        import pyarrow.parquet as pq

        pf = pq.ParquetFile(part.path)
        groups = [part.row_group] if part.row_group is not None else list(range(pf.num_row_groups))
        batches = pf.iter_batches(batch_size=max(rows, 1), row_groups=groups, columns=columns, use_threads=False)
    for batch in batches:
        if rows <= 0:
            return
        batch = batch.slice(0, rows)
        k = np.asarray(batch.column(0).cast(pa.string()).to_pylist(), dtype=object) if key else None
        p = np.column_stack([_numbers(batch.column(i)) for i in range(len(columns) - len(numeric), len(columns))])
        rows -= len(p)
        yield k, p


def _numbers(col) -> np.ndarray:
    """A column as float64 (text that is not a number: NaN)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if pa.types.is_string(col.type) or pa.types.is_large_string(col.type):
        col = pc.if_else(pc.match_substring_regex(col, r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$"),
                         pc.utf8_trim_whitespace(col), pa.scalar(None, pa.string()))
    return np.asarray(to_numpy(col.cast(pa.float64())), float)

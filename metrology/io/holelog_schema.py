"""A hole log's columns: the public contract every reader checks, and the one schema every format's batch is
made into (the readers: :mod:`metrology.io.holelog`).

Columns (a public contract, see docs/measure.md): ``hole_id``; ``time`` (ISO 8601, with or
without a zone offset (without: UTC), or seconds); ``d_<sensor>`` for every sensor of the
layout (mm; blank = no reading); optional ``d_<sensor>_after`` (re-measured after the attitude
adjustment); optional ``cell``, ``panel``, ``temperature_c``. Every other column passes through
(read from CSV as text, verbatim).

Batches come out with ``hole_id`` as string, readings as float64 mm (NaN for blanks), and three columns added for
metro's own use (:data:`INTERNAL`, dropped before results are written): ``_metro_time_s`` (float
seconds since 1970-01-01 UTC), ``_metro_cell`` and ``_metro_panel`` (strings, "" when the log has
none). One schema whatever the format (CSV, Parquet, a hive folder): ``time`` becomes a timestamp
(UTC, to the microsecond), ``temperature_c`` and the commanded pose ``pose_*`` float64
(:data:`NUMERIC`); every other column stays as it was read (a CSV's as text).

Errors are one line naming the file (and line or partition: the reader's ``where`` and ``locate``) and what was
expected.
"""

from __future__ import annotations

import numpy as np

from metrology.io.arrays import from_numpy, strings, to_numpy

__all__ = ["READING_RE", "INTERNAL", "TIME_S", "CELL", "PANEL", "NUMERIC", "HOLE_ID", "POINT_ID", "POSE_ROTATION",
           "POSE_POSITION", "table_key", "is_numeric", "check_columns", "normalise", "repeat", "text_codes",
           "column_seconds"]

#: what a reading looks like in a CSV (blank: no reading)
READING_RE = r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$|^\s*$|^(?i:nan)$"
TIME_S, CELL, PANEL = "_metro_time_s", "_metro_cell", "_metro_panel"
#: the columns metro adds to a batch for its own use
INTERNAL = (TIME_S, CELL, PANEL)
#: each row's hole; and, in a log drilled from a hole table more than once, the table's own id of the row's hole
HOLE_ID, POINT_ID = "hole_id", "point_id"
#: the robot's commanded pose (metrology/sim/forward/log_write.py): ``tcs2panel`` as a rotation vector (deg) and the
#: TCS origin in the panel frame (mm)
POSE_ROTATION = ("pose_rx_deg", "pose_ry_deg", "pose_rz_deg")
POSE_POSITION = ("pose_x_mm", "pose_y_mm", "pose_z_mm")
#: the log's columns of numbers besides the readings (the one result schema: float64 whatever the format)
NUMERIC = ("temperature_c", *POSE_ROTATION, *POSE_POSITION)


def table_key(names) -> str:
    """The column of a log with columns ``names`` that names each row's hole in the hole table: ``point_id``
    where the log has it, else ``hole_id``."""
    return POINT_ID if POINT_ID in names else HOLE_ID


def is_numeric(name: str) -> bool:
    """Whether column ``name`` holds numbers (a reading ``d_*``, or one of :data:`NUMERIC`)."""
    return name.startswith("d_") or name in NUMERIC


def check_columns(log, part, names) -> None:
    """The columns ``names`` of ``log``'s partition ``part`` against the contract and the layout's sensors
    (``log.sensors``); ValueError (one line, naming the partition) otherwise."""
    where = log.where(part)
    for need in ("hole_id", "time"):
        if need not in names:
            raise ValueError(f"{where}: no '{need}' column (a hole log needs hole_id, time and d_<sensor> for each "
                             f"sensor: {', '.join(log.sensors)})")
    readings = [c for c in names if c.startswith("d_")]
    known = {f"d_{s}" for s in log.sensors} | {f"d_{s}_after" for s in log.sensors}
    unknown = [c for c in readings if c not in known]
    if unknown:
        raise ValueError(f"{where}: column {unknown[0]} names no sensor of the layout ({', '.join(log.sensors)}): "
                         f"expected d_<sensor> or d_<sensor>_after")
    missing = [s for s in log.sensors if f"d_{s}" not in names]
    if missing:
        raise ValueError(f"{where}: no reading column for {', '.join(missing)} (expected d_{missing[0]}): the log's "
                         f"sensors do not match the layout's ({', '.join(log.sensors)})")
    after = [s for s in log.sensors if f"d_{s}_after" in names]
    if after and len(after) != len(log.sensors):
        lack = [s for s in log.sensors if s not in after]
        raise ValueError(f"{where}: after-readings for {', '.join(after)} but not for {', '.join(lack)} "
                         f"(expected d_<sensor>_after for every sensor, or none)")


def column_seconds(log, part, col, first_row):
    """(N,) float64 seconds since 1970-01-01 UTC of ``time`` column ``col`` (numbers, timestamps or ISO 8601
    text), rows of ``log``'s partition ``part`` from its 0-based row ``first_row`` on; ValueError (one line naming
    the row, by ``log.locate``) on a value that is none of those."""
    import pyarrow as pa
    import pyarrow.compute as pc

    t = col.type
    if pa.types.is_timestamp(t):
        return to_numpy(pc.cast(col, pa.timestamp("ns", tz=t.tz)).cast(pa.int64())) / 1e9
    if pa.types.is_integer(t) or pa.types.is_floating(t):
        return to_numpy(col.cast(pa.float64()))
    if pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_dictionary(t):
        col = col.cast(pa.string()) if not pa.types.is_dictionary(t) else col.cast(pa.string())
        for target in (pa.float64(), pa.timestamp("ns", tz="UTC"), pa.timestamp("ns")):
            try:
                out = col.cast(target)
            except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
                continue
            return to_numpy(out) if target == pa.float64() else to_numpy(out.cast(pa.int64())) / 1e9
        for i, v in enumerate(col.to_pylist()):  # the error path: find the value at fault
            ok = False
            for target in (pa.float64(), pa.timestamp("ns", tz="UTC"), pa.timestamp("ns")):
                try:
                    pa.array([v], pa.string()).cast(target)
                    ok = True
                    break
                except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
                    pass
            if not ok:
                raise ValueError(f"{log.locate(part, first_row + i)}: time {v!r} is neither ISO 8601 "
                                 f"(2026-11-25T08:00:00Z) nor seconds")
        raise ValueError(f"{log.where(part)}: the time column mixes formats (ISO 8601 with a zone offset, without one, seconds): expected one")
    raise ValueError(f"{log.where(part)}: time column of type {t}, expected ISO 8601 text, a timestamp or seconds")


def normalise(log, part, table, first_row):
    """``table``, rows of ``log``'s partition ``part`` from its 0-based row ``first_row`` on, in the one schema
    (module docstring): numbers float64, ``time`` a UTC timestamp, the columns :data:`INTERNAL` added; ValueError
    (one line naming the row, by ``log.locate``) on a column or value that is not what the contract says."""
    import pyarrow as pa

    cols, names = {}, table.column_names
    for c in names:
        col = table.column(c)
        if is_numeric(c):
            if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type) or pa.types.is_null(col.type)):
                raise ValueError(f"{log.where(part)}: column {c} is {col.type}, expected numbers"
                                 + (" (mm)" if c.startswith("d_") else ""))
            col = col.cast(pa.float64())
        elif c in ("hole_id", "cell", "panel"):
            col = col.cast(pa.string())
        cols[c] = col
    time_s = column_seconds(log, part, table.column("time"), first_row)
    bad = np.flatnonzero(~np.isfinite(time_s))
    if bad.size:
        raise ValueError(f"{log.locate(part, first_row + int(bad[0]))}: time is blank, expected ISO 8601 or seconds")
    cols[TIME_S] = from_numpy(time_s)
    # one result schema whatever the log's format: time a timestamp (UTC, to the microsecond)
    cols["time"] = from_numpy(np.round(time_s * 1e6).astype(np.int64), pa.timestamp("us", tz="UTC"))
    for c, name in (("cell", CELL), ("panel", PANEL)):
        cols[name] = cols[c] if c in cols else repeat("", table.num_rows)
    nulls = cols["hole_id"].null_count
    if nulls:
        i = int(np.flatnonzero(to_numpy(cols["hole_id"].is_null()))[0])
        raise ValueError(f"{log.locate(part, first_row + i)}: hole_id is blank")
    return pa.table(cols)


def repeat(value: str, n: int):
    """A pyarrow StringArray of ``value`` on ``n`` rows (a dictionary of one value, decoded)."""
    return strings([value]).take(from_numpy(np.zeros(n, np.int32)))


def text_codes(col):
    """A string column with few values (cell, panel) by its dictionary: ``(codes (N,) int64, values list)``."""
    import pyarrow.compute as pc

    enc = pc.dictionary_encode(col).combine_chunks()
    return to_numpy(enc.indices).astype(np.int64), enc.dictionary.to_pylist()

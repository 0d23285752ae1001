"""A drilling cell's hole log: read in batches (CSV, stdin, Parquet, hive-partitioned Parquet).

Columns (a public contract, see docs/measure.md): ``hole_id``; ``time`` (ISO 8601, with or
without a zone offset (without: UTC), or seconds); ``d_<sensor>`` for every sensor of the
layout (mm; blank = no reading); optional ``d_<sensor>_after`` (re-measured after the attitude
adjustment); optional ``cell``, ``panel``, ``temperature_c``. Every other column passes through
(read from CSV as text, verbatim).

A log is a list of *partitions* (a CSV or Parquet file is one; a folder of Parquet files is one
per file, with its hive keys such as ``cell=C1/date=2026-11-25``), each read in batches of at most
``batch_rows`` rows, so memory stays bounded whatever the log's size. Batches come out with
``hole_id`` as string, readings as float64 mm (NaN for blanks), and three columns added for
metro's own use (:data:`INTERNAL`, dropped before results are written): ``_metro_time_s`` (float
seconds since 1970-01-01 UTC), ``_metro_cell`` and ``_metro_panel`` (strings, "" when the log has
none). One schema whatever the format (CSV, Parquet, a hive folder): ``time`` becomes a timestamp
(UTC, to the microsecond), ``temperature_c`` and the commanded pose ``pose_*`` float64
(:data:`NUMERIC`); every other column stays as it was read (a CSV's as text).

Errors are one line naming the file (and line or partition) and what was expected; pyarrow is
imported only here, when a log is read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from metrology.io.arrays import from_numpy, strings, to_numpy

__all__ = ["HoleLog", "CsvLog", "ParquetLog", "Partition", "open_log", "batch_of", "BATCH_ROWS", "LOG_SUFFIXES", "READING_RE", "INTERNAL", "TIME_S",
           "CELL", "PANEL", "NUMERIC", "HOLE_ID", "POINT_ID", "POSE_ROTATION", "POSE_POSITION", "table_key", "text_codes",
           "time_seconds"]

#: rows per batch: a few tens of MB of readings, large enough for numpy to run at full speed
BATCH_ROWS = 1 << 18
LOG_SUFFIXES = (".csv", ".parquet")
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


def table_key(names) -> str:
    """The column of a log with columns ``names`` that names each row's hole in the hole table: ``point_id``
    where the log has it, else ``hole_id``."""
    return POINT_ID if POINT_ID in names else HOLE_ID


@dataclass(frozen=True)
class Partition:
    """One file of a log.

    Attributes
    ----------
    path : str, the file ("<stdin>" for a spooled stdin)
    relative : str, its path below the log's folder (the file name for a single file): where a
        partitioned output writes its results
    keys : dict, hive partition keys (``{"cell": "C1", "date": "2026-11-25"}``), {} for none
    row_group : int or None, only this row group of a Parquet file (a task of a Dask run on one file)
    first_row : int, the file's row (0-based) at which the partition starts
    """

    path: str
    relative: str
    keys: dict = field(default_factory=dict)
    row_group: int | None = None
    first_row: int = 0


@dataclass(frozen=True)
class HoleLog:
    """A log to read: its partitions and the sensors it must carry. A format is a reader
    (:class:`CsvLog`, :class:`ParquetLog`): what its files hold (:meth:`columns`), their rows in
    batches (:meth:`batches`), and how an error names a partition (:meth:`where`) and a row
    (:meth:`locate`).

    Attributes
    ----------
    source : str, the file or folder (resolved)
    partitions : tuple of Partition, in the log's order
    sensors : tuple of str, the layout's
    batch_rows : int, rows per batch at most
    display : str, how outputs and errors name the log
    skip : tuple of str, columns of a Parquet file left unread (what the run does not need: the commanded
        pose without a panel; reading a 1e6-hole log's 7 such columns cost 0.2-0.5 s of CPU)
    """

    source: str
    partitions: tuple
    sensors: tuple
    batch_rows: int = BATCH_ROWS
    display: str = ""
    skip: tuple = field(default=(), kw_only=True)

    @property
    def partitioned(self) -> bool:
        """A folder of files (one partition each), mirrored by a folder output."""
        return False

    def where(self, part: Partition) -> str:
        """How an error names a partition: the log, and the partition's file in a folder."""
        return f"{self.display}: partition {part.relative}" if self.partitioned else self.display

    def line(self, row: int) -> str:
        """How an error names a row (0-based) of a partition's file."""
        return f"row {row + 1}"

    def locate(self, part: Partition, row: int) -> str:
        """How an error names row ``row`` (0-based) of ``part``'s file: the partition and the row."""
        return f"{self.where(part)} {self.line(row)}"

    def columns(self, part: Partition, with_keys: bool = True) -> list:
        """The partition's column names (with its hive keys unless ``with_keys`` is False)."""
        raise NotImplementedError

    def file_columns(self, part: Partition) -> list:
        """The columns the partition's file itself holds (not its hive keys)."""
        return self.columns(part, with_keys=False)

    def has_rows(self, part: Partition) -> bool:
        """Whether the partition holds a row (read before any work: an empty log is refused first)."""
        raise NotImplementedError

    def by_row_group(self) -> "HoleLog":
        """The same log with each row group of a single Parquet file as its own partition (the
        tasks of a Dask run); any other log as it is."""
        return self

    def _tables(self, part: Partition):
        """The partition's rows as read, in tables of at most ``batch_rows`` rows."""
        raise NotImplementedError

    def batches(self, part: Partition):
        """Yield ``(table, first_row)``: normalised pyarrow Tables of ``part`` in file order;
        ``first_row`` is the 0-based row of the partition at which the batch starts."""
        row = part.first_row
        for table in self._tables(part):
            yield _normalise(self, part, table, row), row
            row += table.num_rows


@dataclass(frozen=True)
class CsvLog(HoleLog):
    """A CSV hole log (one file, one partition): readings read as numbers, other columns as text."""

    def line(self, row: int) -> str:
        return f"line {row + 2}"  # the header is line 1

    def columns(self, part: Partition, with_keys: bool = True) -> list:
        with open(part.path, "rb") as fh:
            head = fh.readline().decode("utf-8-sig", errors="replace").strip()
        if not head:
            raise ValueError(f"{self.display}: empty file, expected a header line with hole_id, time and d_<sensor> "
                             f"columns")
        import csv

        return [c.strip() for c in next(csv.reader([head]))]

    def has_rows(self, part: Partition) -> bool:
        with open(part.path, "rb") as fh:
            fh.readline()
            return any(line.strip() for line in fh)

    def _tables(self, part: Partition):
        return _csv_batches(self, part)

    def readable(self, part: Partition):
        """What pyarrow's CSV reader opens for ``part``: its file (a reader of lines in memory,
        :class:`metrology.io.loglines.LinesLog`, gives a buffer)."""
        return part.path


@dataclass(frozen=True)
class ParquetLog(HoleLog):
    """A Parquet hole log: one file, or a folder of files with hive keys (one partition each)."""

    @property
    def partitioned(self) -> bool:
        return Path(self.source).is_dir()

    def columns(self, part: Partition, with_keys: bool = True) -> list:
        import pyarrow.parquet as pq

        try:
            names = pq.read_schema(part.path).names
        except Exception as exc:  # pyarrow raises ArrowInvalid, OSError ... on a corrupt or truncated file
            raise ValueError(f"{self.where(part)}: not a readable Parquet file ({_short(exc)})") from None
        return names + [k for k in part.keys if k not in names] if with_keys else names

    def has_rows(self, part: Partition) -> bool:
        import pyarrow.parquet as pq

        return pq.ParquetFile(part.path).metadata.num_rows > 0

    def by_row_group(self) -> "HoleLog":
        import dataclasses

        import pyarrow.parquet as pq

        if self.partitioned or len(self.partitions) != 1:
            return self
        part = self.partitions[0]
        meta = pq.ParquetFile(part.path).metadata
        parts, row = [], 0
        for g in range(meta.num_row_groups):
            parts.append(Partition(part.path, f"{part.relative}#row-group-{g}", {}, g, row))
            row += meta.row_group(g).num_rows
        return dataclasses.replace(self, partitions=tuple(parts)) if parts else self

    def _tables(self, part: Partition):
        return _parquet_batches(self, part)


#: the reader of each file suffix
READERS = {".csv": CsvLog, ".parquet": ParquetLog}


def open_log(path, sensors, batch_rows: int = BATCH_ROWS, display: str | None = None) -> HoleLog:
    """A hole log at ``path`` (a ``.csv`` or ``.parquet`` file, or a folder of Parquet files)
    for a layout with ``sensors``; its columns are checked against them (ValueError)."""
    name = display or str(path)
    if not Path(path).exists():
        raise ValueError(f"{name}: no such file or folder")
    p = Path(path).resolve()  # workers started in another folder read the same files
    if p.is_dir():
        files = sorted(q for q in p.rglob("*.parquet") if not any(part.startswith((".", "_")) for part in q.relative_to(p).parts))
        if not files:
            raise ValueError(f"{name}: a folder of hole logs must hold .parquet files (hive-partitioned, e.g. "
                             f"cell=C1/date=2026-11-25/part-0.parquet); found none")
        parts = tuple(Partition(str(q), str(q.relative_to(p)), _hive_keys(q.relative_to(p))) for q in files)
        log = ParquetLog(str(p), parts, tuple(sensors), batch_rows, name)
    else:
        suffix = p.suffix.lower()
        if suffix not in LOG_SUFFIXES:
            raise ValueError(f"{name}: a hole log must be one of {', '.join(LOG_SUFFIXES)} (or a folder of .parquet), "
                             f"got '{p.suffix}'")
        log = READERS[suffix](str(p), (Partition(str(p), p.name, {}),), tuple(sensors), batch_rows, name)
    for part in log.partitions:
        _check_columns(log, part, log.columns(part))
    if not any(log.has_rows(part) for part in log.partitions):
        raise ValueError(f"{name}: the log has no rows (a header only): no hole to measure")
    return log


def batch_of(table, sensors, name: str = "<memory>"):
    """A pyarrow Table of log rows already in memory (a simulator's, a test's) made into the batch a
    read gives (the same checks, the columns :data:`INTERNAL` added), as if read from a file ``name``."""
    log = ParquetLog(name, (), tuple(sensors), max(table.num_rows, 1), name)
    part = Partition(name, name, {})
    _check_columns(log, part, table.column_names)
    return _normalise(log, part, table, 0)


def _hive_keys(rel: Path) -> dict:
    keys = {}
    for piece in rel.parts[:-1]:
        if "=" in piece:
            k, v = piece.split("=", 1)
            keys[k] = v
    return keys


def _short(exc) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _check_columns(log, part, names) -> None:
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


def _csv_types(log, names):
    import pyarrow as pa

    types = {c: pa.string() for c in names}
    for c in names:
        if _numeric(c):
            types[c] = pa.float64()
    return types


#: the log's columns of numbers besides the readings (the one result schema: float64 whatever the format)
NUMERIC = ("temperature_c", *POSE_ROTATION, *POSE_POSITION)


def _numeric(name: str) -> bool:
    return name.startswith("d_") or name in NUMERIC


def _csv_batches(log, part):
    import pyarrow as pa
    import pyarrow.csv as pcsv

    names = log.columns(part)
    opts = pcsv.ConvertOptions(column_types=_csv_types(log, names), strings_can_be_null=False,
                               null_values=["", "NaN", "nan", "NA"])
    read = pcsv.ReadOptions(block_size=max(1 << 20, log.batch_rows * 64))
    try:
        reader = pcsv.open_csv(log.readable(part), read_options=read, convert_options=opts)
        for batch in reader:
            table = pa.Table.from_batches([batch])
            for i in range(0, table.num_rows, log.batch_rows):
                yield table.slice(i, log.batch_rows)
    except pa.ArrowInvalid as exc:
        raise ValueError(_locate_csv_error(log, part, names, exc)) from None


def _locate_csv_error(log, part, names, exc) -> str:
    """The one-line error of a CSV pyarrow would not convert: the line and value at fault."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pcsv

    numeric = [c for c in names if c.startswith("d_") or c == "temperature_c"]
    try:
        reader = pcsv.open_csv(log.readable(part), convert_options=pcsv.ConvertOptions(
            column_types={c: pa.string() for c in names}, strings_can_be_null=False))
        row = 0
        for batch in reader:
            for c in numeric:
                ok = pc.match_substring_regex(batch.column(c), READING_RE).to_numpy(zero_copy_only=False)
                bad = np.flatnonzero(~ok)
                if bad.size:
                    value = batch.column(c)[int(bad[0])].as_py()
                    return (f"{log.locate(part, row + int(bad[0]))}: {c} = {value!r} is not a number "
                            f"({'a reading in mm, or blank for no reading' if c.startswith('d_') else 'deg C'})")
            row += batch.num_rows
    except pa.ArrowInvalid as exc2:
        return f"{log.display}: not a readable CSV hole log ({_short(exc2)})"
    return f"{log.display}: not a readable CSV hole log ({_short(exc)})"


def _parquet_batches(log, part):
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        # one row group at a time, without read-ahead: memory is bounded by the larger of a batch and
        # a row group (pyarrow's iter_batches reads ahead: 260 MB against 135 MB on a 1e6-hole file)
        pf = pq.ParquetFile(part.path, pre_buffer=False)
        first = part.first_row
        columns = [c for c in pf.schema_arrow.names if c not in log.skip] if log.skip else None
        for g in (range(pf.num_row_groups) if part.row_group is None else (part.row_group,)):
            group = pf.read_row_group(g, columns=columns, use_threads=False)
            for start in range(0, group.num_rows, log.batch_rows):
                table = group.slice(start, log.batch_rows)
                for k, v in part.keys.items():
                    if k in table.column_names:
                        _check_key(log, part, table, k, v, first + start)
                    else:
                        table = table.append_column(k, _repeat(v, table.num_rows))
                yield table
            first += group.num_rows
            del group
    except (pa.ArrowInvalid, OSError) as exc:
        raise ValueError(f"{log.where(part)}: not a readable Parquet file ({_short(exc)})") from None


def _check_key(log, part, table, key, value, first_row) -> None:
    """A column that is also the partition's hive key must hold the folder's value on every row."""
    import pyarrow as pa
    import pyarrow.compute as pc

    col = table.column(key).cast(pa.string())
    bad = to_numpy(pc.fill_null(pc.not_equal(col, value), True))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{log.locate(part, first_row + i)}: {key} = {col[i].as_py()!r} disagrees with its folder's "
                         f"{key}={value} (a partition's file must hold its folder's key, or leave the column out)")


def _time_seconds(log, part, col, first_row):
    """float64 seconds since 1970-01-01 UTC from a number, timestamp or ISO 8601 string column."""
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


def _normalise(log, part, table, first_row):
    import pyarrow as pa

    cols, names = {}, table.column_names
    for c in names:
        col = table.column(c)
        if _numeric(c):
            if not (pa.types.is_floating(col.type) or pa.types.is_integer(col.type) or pa.types.is_null(col.type)):
                raise ValueError(f"{log.where(part)}: column {c} is {col.type}, expected numbers"
                                 + (" (mm)" if c.startswith("d_") else ""))
            col = col.cast(pa.float64())
        elif c in ("hole_id", "cell", "panel"):
            col = col.cast(pa.string())
        cols[c] = col
    time_s = _time_seconds(log, part, table.column("time"), first_row)
    bad = np.flatnonzero(~np.isfinite(time_s))
    if bad.size:
        raise ValueError(f"{log.locate(part, first_row + int(bad[0]))}: time is blank, expected ISO 8601 or seconds")
    cols[TIME_S] = from_numpy(time_s)
    # one result schema whatever the log's format: time a timestamp (UTC, to the microsecond)
    cols["time"] = from_numpy(np.round(time_s * 1e6).astype(np.int64), pa.timestamp("us", tz="UTC"))
    for c, name in (("cell", CELL), ("panel", PANEL)):
        cols[name] = cols[c] if c in cols else _repeat("", table.num_rows)
    nulls = cols["hole_id"].null_count
    if nulls:
        i = int(np.flatnonzero(to_numpy(cols["hole_id"].is_null()))[0])
        raise ValueError(f"{log.locate(part, first_row + i)}: hole_id is blank")
    return pa.table(cols)


def _repeat(value: str, n: int):
    """A pyarrow StringArray of ``value`` on ``n`` rows (a dictionary of one value, decoded)."""
    return strings([value]).take(from_numpy(np.zeros(n, np.int32)))


def text_codes(col):
    """A string column with few values (cell, panel) by its dictionary: ``(codes (N,) int64, values list)``."""
    import pyarrow.compute as pc

    enc = pc.dictionary_encode(col).combine_chunks()
    return to_numpy(enc.indices).astype(np.int64), enc.dictionary.to_pylist()


def time_seconds(col) -> np.ndarray:
    """(N,) float seconds since 1970-01-01 UTC of a ``time`` column already read once (a results
    file's: a number, timestamp or ISO 8601 string column), as a batch's ``_metro_time_s``."""
    display = "<results>"
    log = ParquetLog(display, (), (), BATCH_ROWS, display)
    return _time_seconds(log, Partition(display, display, {}), col, 0)

"""A drilling cell's hole log opened by its path (a CSV file, stdin spooled to one, a Parquet file, a folder of
hive-partitioned Parquet files) or given as rows in memory, its columns checked against the layout before any row
is read.

What a log is and how it is read in batches: :mod:`metrology.io.holelog_reader`; its columns and the one schema
every format's batch comes out in: :mod:`metrology.io.holelog_schema`; the formats:
:mod:`metrology.io.holelog_csv`, :mod:`metrology.io.holelog_parquet` (a new format is a reader there and an entry
of :data:`READERS`). Errors are one line naming the file (and line or partition) and what was expected; pyarrow is
imported only when a log is read.
"""

from __future__ import annotations

from pathlib import Path

from metrology.io.holelog_csv import CsvLog
from metrology.io.holelog_parquet import ParquetLog, folder_partitions
from metrology.io.holelog_reader import BATCH_ROWS, HoleLog, Partition
from metrology.io.holelog_schema import check_columns, normalise

__all__ = ["open_log", "batch_of", "READERS", "LOG_SUFFIXES"]

LOG_SUFFIXES = (".csv", ".parquet")
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
        log = ParquetLog(str(p), folder_partitions(p, name), tuple(sensors), batch_rows, name)
    else:
        suffix = p.suffix.lower()
        if suffix not in LOG_SUFFIXES:
            raise ValueError(f"{name}: a hole log must be one of {', '.join(LOG_SUFFIXES)} (or a folder of .parquet), "
                             f"got '{p.suffix}'")
        log = READERS[suffix](str(p), (Partition(str(p), p.name, {}),), tuple(sensors), batch_rows, name)
    for part in log.partitions:
        check_columns(log, part, log.columns(part))
    if not any(log.has_rows(part) for part in log.partitions):
        raise ValueError(f"{name}: the log has no rows (a header only): no hole to measure")
    return log


def batch_of(table, sensors, name: str = "<memory>"):
    """A pyarrow Table of log rows already in memory (a simulator's, a test's) made into the batch a
    read gives (the same checks, the columns :data:`~metrology.io.holelog_schema.INTERNAL` added), as if read
    from a file ``name``."""
    log = ParquetLog(name, (), tuple(sensors), max(table.num_rows, 1), name)
    part = Partition(name, name, {})
    check_columns(log, part, table.column_names)
    return normalise(log, part, table, 0)

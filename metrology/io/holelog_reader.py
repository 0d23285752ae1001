"""What a hole log's reader is: a log as a list of *partitions* (a CSV or Parquet file is one; a folder of Parquet
files is one per file, with its hive keys such as ``cell=C1/date=2026-11-25``), each read in batches of at most
``batch_rows`` rows, so memory stays bounded whatever the log's size, and how its errors name a partition and a
row. Each format is a subclass (:mod:`metrology.io.holelog_csv`, :mod:`metrology.io.holelog_parquet`; lines a live
stream gave: :mod:`metrology.io.loglines`); :func:`metrology.io.holelog.open_log` picks one by the path. Every
batch comes out in the one schema of :mod:`metrology.io.holelog_schema`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from metrology.io.holelog_schema import column_seconds, normalise

__all__ = ["HoleLog", "Partition", "BATCH_ROWS", "short", "time_seconds"]

#: rows per batch: a few tens of MB of readings, large enough for numpy to run at full speed
BATCH_ROWS = 1 << 18


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
    (:class:`~metrology.io.holelog_csv.CsvLog`, :class:`~metrology.io.holelog_parquet.ParquetLog`): what its files
    hold (:meth:`columns`), their rows in batches (:meth:`batches`), and how an error names a partition
    (:meth:`where`) and a row (:meth:`locate`).

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
            yield normalise(self, part, table, row), row
            row += table.num_rows


def short(exc) -> str:
    """The first line of an exception's message (its type's name where it has none): what a one-line error quotes."""
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def time_seconds(col):
    """(N,) float seconds since 1970-01-01 UTC of a ``time`` column already read once (a results file's: a number,
    timestamp or ISO 8601 string column), as a batch's ``_metro_time_s``; an error names the row as a log's would
    (``<results> row 3``)."""
    display = "<results>"
    return column_seconds(HoleLog(display, (), (), display=display), Partition(display, display), col, 0)

"""A hole log's lines already read from a stream (``metro measure --follow``): read by
:mod:`metrology.io.holelog_csv`'s reader from memory, so they come out as a file's batch does (the
same column types, checks and one-line errors), each error naming its line of the stream.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

from metrology.io.holelog import batch_of
from metrology.io.holelog_csv import CsvLog
from metrology.io.holelog_reader import Partition
from metrology.io.holelog_schema import NUMERIC

__all__ = ["LinesLog", "lines_log", "read_lines", "check_header", "header_line"]


@dataclass(frozen=True)
class LinesLog(CsvLog):
    """Lines of a CSV hole log held in memory, with the stream's header.

    Attributes
    ----------
    header : tuple of str, the column names (stripped)
    text : bytes, the header line then the lines, UTF-8
    numbers : tuple of int, each row's line number in the stream (the header is line 1)
    """

    header: tuple = ()
    text: bytes = b""
    numbers: tuple = ()

    def line(self, row: int) -> str:
        return f"line {self.numbers[row]}"

    def columns(self, part: Partition, with_keys: bool = True) -> list:
        return list(self.header)

    def has_rows(self, part: Partition) -> bool:
        return bool(self.numbers)

    def readable(self, part: Partition):
        return io.BytesIO(self.text)


def header_line(header) -> str:
    """The header as one CSV line (names quoted where CSV needs it)."""
    import csv

    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(header)
    return buf.getvalue()


def lines_log(header, lines, numbers, sensors, display) -> LinesLog:
    """``lines`` (str, each ending with its newline) under ``header`` as a hole log held in memory, line ``numbers``
    (int) of the stream ``display``: what the readers of a log's first rows
    (:mod:`metrology.io.holelog_sample`) read as they read a file."""
    text = (header_line(header) + "".join(lines)).encode("utf-8")
    return LinesLog(display, (Partition(display, display, {}),), tuple(sensors), max(len(numbers), 1), display,
                    tuple(header), text, tuple(numbers))


def check_header(header, sensors, display: str) -> None:
    """The header's columns checked as a log file's are (ValueError, one line naming ``display``)."""
    import pyarrow as pa

    empty = pa.table({c: pa.array([], pa.float64() if c.startswith("d_") or c in NUMERIC else pa.string())
                      for c in header})
    batch_of(empty, sensors, display)


def read_lines(header, lines, numbers, sensors, display: str):
    """``lines`` (str, each ending with its newline) under ``header``: the normalised pyarrow Table a
    log file's batch is (:meth:`metrology.io.holelog_reader.HoleLog.batches`); ``numbers`` (int) are
    their line numbers in the stream, which errors name. ValueError (one line) on a value that is
    not what its column holds."""
    import pyarrow as pa

    log = lines_log(header, lines, numbers, sensors, display)
    tables = [t for t, _ in log.batches(log.partitions[0])]
    table = tables[0] if len(tables) == 1 else pa.concat_tables(tables)
    if table.num_rows != len(numbers):  # pyarrow skipped a line (empty) or read one as two: name the lines
        raise ValueError(f"{display}: lines {numbers[0]}-{numbers[-1]}: {table.num_rows} rows read from "
                         f"{len(numbers)} lines")
    return table

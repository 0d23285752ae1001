"""A CSV hole log (one file, one partition; or lines held in memory: :mod:`metrology.io.loglines`), read by
pyarrow's CSV reader in batches: readings and the log's other numbers (:data:`~metrology.io.holelog_schema.NUMERIC`)
read as numbers, every other column as text; a value pyarrow would not convert named by its line and column.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.io.holelog_reader import HoleLog, Partition, short
from metrology.io.holelog_schema import READING_RE, is_numeric

__all__ = ["CsvLog"]


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


def _csv_types(names):
    import pyarrow as pa

    types = {c: pa.string() for c in names}
    for c in names:
        if is_numeric(c):
            types[c] = pa.float64()
    return types


def _csv_batches(log, part):
    import pyarrow as pa
    import pyarrow.csv as pcsv

    names = log.columns(part)
    opts = pcsv.ConvertOptions(column_types=_csv_types(names), strings_can_be_null=False,
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
        return f"{log.display}: not a readable CSV hole log ({short(exc2)})"
    return f"{log.display}: not a readable CSV hole log ({short(exc)})"

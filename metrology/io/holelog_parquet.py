"""A Parquet hole log: one file, or a folder of files with hive keys (``cell=C1/date=2026-11-25/part-0.parquet``),
one partition each; read a row group at a time, each batch given its partition's keys as columns (a column the
file holds too must agree with its folder's key on every row).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metrology.io.arrays import to_numpy
from metrology.io.holelog_reader import HoleLog, Partition, short
from metrology.io.holelog_schema import repeat

__all__ = ["ParquetLog", "folder_partitions"]


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
            raise ValueError(f"{self.where(part)}: not a readable Parquet file ({short(exc)})") from None
        return names + [k for k in part.keys if k not in names] if with_keys else names

    def has_rows(self, part: Partition) -> bool:
        import pyarrow.parquet as pq

        return pq.ParquetFile(part.path).metadata.num_rows > 0

    def by_row_group(self) -> "HoleLog":
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


def folder_partitions(folder: Path, name: str) -> tuple:
    """The partitions of a folder of Parquet files (``folder`` resolved; ``name``: how errors name it), in the
    order of their paths, each with its hive keys; files and folders whose name starts with ``.`` or ``_`` are
    not the log's. ValueError (one line) where there is none."""
    files = sorted(q for q in folder.rglob("*.parquet")
                   if not any(part.startswith((".", "_")) for part in q.relative_to(folder).parts))
    if not files:
        raise ValueError(f"{name}: a folder of hole logs must hold .parquet files (hive-partitioned, e.g. "
                         f"cell=C1/date=2026-11-25/part-0.parquet); found none")
    return tuple(Partition(str(q), str(q.relative_to(folder)), _hive_keys(q.relative_to(folder))) for q in files)


def _hive_keys(rel: Path) -> dict:
    keys = {}
    for piece in rel.parts[:-1]:
        if "=" in piece:
            k, v = piece.split("=", 1)
            keys[k] = v
    return keys


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
                        table = table.append_column(k, repeat(v, table.num_rows))
                yield table
            first += group.num_rows
            del group
    except (pa.ArrowInvalid, OSError) as exc:
        raise ValueError(f"{log.where(part)}: not a readable Parquet file ({short(exc)})") from None


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

"""Per-point and per-pose tables the commands write for other tools: CSV, or Parquet (pyarrow,
loaded only when a ``.parquet`` file is asked for), chosen by the suffix; written atomically.

A format plugs in by one writer and one entry of :data:`TABLE_WRITERS`.
"""

from __future__ import annotations

import csv
import math

import numpy as np

from metrology.io.atomic import atomic_path, check_output_file

__all__ = ["TABLE_WRITERS", "check_table_path", "write_table"]


def _cell(v):
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return "" if not math.isfinite(float(v)) else repr(float(v))  # shortest text that reads back exactly
    return v


def _write_csv(tmp, columns: dict) -> None:
    names = list(columns)
    n = len(next(iter(columns.values()))) if columns else 0
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(names)
        for i in range(n):
            w.writerow([_cell(columns[k][i]) for k in names])


def _write_parquet(tmp, columns: dict) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({k: np.asarray(v) for k, v in columns.items()}), str(tmp))


#: suffix -> writer(tmp_path, columns)
TABLE_WRITERS = {".csv": _write_csv, ".parquet": _write_parquet}


def check_table_path(path, option: str, suffixes=tuple(TABLE_WRITERS)):
    """Refuse a table output before any work (ValueError naming ``option``): a bad folder, a suffix
    not in ``suffixes``, a ``.parquet`` file without pyarrow installed."""
    p = check_output_file(path, option, set(suffixes))
    if p.suffix.lower() == ".parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise ValueError(f"{option} {path}: writing Parquet needs pyarrow (pip install pyarrow); or give a .csv "
                             "file") from None
    return p


def write_table(path, columns: dict) -> None:
    """Write ``columns`` (name -> (m,) values, all the same length) to ``path`` atomically, in the
    format of its suffix (:data:`TABLE_WRITERS`)."""
    from pathlib import Path

    writer = TABLE_WRITERS[Path(path).suffix.lower()]
    with atomic_path(path) as tmp:
        writer(tmp, columns)

"""How far two runs of benchmarks/golden_measure.sh differ, per output table: rows, statuses changed, and per
numeric column the largest difference (absolute and relative to the column's median magnitude).

    python benchmarks/golden_diff.py OUT_BEFORE OUT_AFTER

Reads every ``.csv`` output (a folder output: its ``.csv`` / ``.parquet`` files, concatenated); files equal byte
for byte are listed as such.
"""

from __future__ import annotations

import argparse
import filecmp
from pathlib import Path

import numpy as np


def _table(path: Path):
    import pyarrow as pa
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.suffix in (".csv", ".parquet") and not p.name.startswith("_"))
        return pa.concat_tables([_table(p) for p in files], promote_options="default") if files else None
    if path.suffix == ".parquet":
        return pq.read_table(path)
    return pcsv.read_csv(path)


def compare(a: Path, b: Path) -> str:
    ta, tb = _table(a), _table(b)
    if ta is None or tb is None:
        return f"{a.name}: no table"
    if ta.num_rows != tb.num_rows or ta.column_names != tb.column_names:
        return f"{a.name}: {ta.num_rows} rows / {tb.num_rows}; columns equal: {ta.column_names == tb.column_names}"
    out = [f"{a.name}: {ta.num_rows} rows"]
    if "status" in ta.column_names:
        sa = np.asarray(ta.column("status").to_pylist(), object)
        sb = np.asarray(tb.column("status").to_pylist(), object)
        out.append(f"status changed {int((sa != sb).sum())}")
    for c in ta.column_names:
        try:
            x = np.asarray(ta.column(c).to_numpy(zero_copy_only=False), float)
            y = np.asarray(tb.column(c).to_numpy(zero_copy_only=False), float)
        except Exception:
            continue
        both = np.isfinite(x) & np.isfinite(y)
        nan_changed = int((np.isfinite(x) != np.isfinite(y)).sum())
        if not both.any() and not nan_changed:
            continue
        d = np.abs(x[both] - y[both])
        if d.size and d.max() == 0 and not nan_changed:
            continue
        scale = np.median(np.abs(x[both])) if both.any() else 1.0
        out.append(f"{c}: max |diff| {d.max() if d.size else 0:.3g} ({d.max() / scale if d.size and scale else 0:.2g} of "
                   f"its median), median |diff| {np.median(d) if d.size else 0:.3g}" + (f", NaN changed {nan_changed}"
                                                                                       if nan_changed else ""))
    return "; ".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    args = ap.parse_args(argv)
    for a in sorted(args.before.iterdir()):
        b = args.after / a.name
        if not b.exists():
            print(f"{a.name}: missing after")
            continue
        same = filecmp.cmp(a, b, shallow=False) if a.is_file() else not _dirs_differ(a, b)
        if same:
            print(f"{a.name}: identical")
        elif a.suffix == ".csv" or a.is_dir():
            print(compare(a, b))
        else:
            print(f"{a.name}: differs")
    for b in sorted(args.after.iterdir()):
        if not (args.before / b.name).exists():
            print(f"{b.name}: new")


def _dirs_differ(a, b) -> bool:
    c = filecmp.dircmp(a, b)
    return bool(c.left_only or c.right_only or c.diff_files or c.funny_files
                or any(_dirs_differ(a / s, b / s) for s in c.common_dirs))


if __name__ == "__main__":
    main()

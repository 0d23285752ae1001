"""What the output contract of ``metro measure`` costs alone: the plain pyarrow+numpy micro-plane script
(``bench_measure.BASELINE``) against the same script reading the columns of the log ``metro measure`` reads (all but
the commanded pose and the temperature, without a panel or a head term that needs them) and writing every column
``metro measure`` writes (its 13 result columns, the reason one fixed text per row, the log's columns that name
the hole passed through: ``hole_id``, ``time``, ``cell``, ``panel``; encoded as
``metrology.io.holeout.parquet_options`` encodes them), no uncertainty, verdict, drift watch or
summary: the floor a ratio of ``metro measure`` to the plain script stands on.

    python benchmarks/measure_io_floor.py LOG.parquet LAYOUT.toml [--repeat 4]

Each round runs both scripts in turn (CPU seconds, user + system, of each process) and prints their ratio.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_measure import BASELINE, RUN, _ENV  # noqa: E402

#: the columns metro reads of a log without a panel: all but its numeric inputs it does not need (the commanded pose,
#: the temperature): ``metrology.jobs.measure._unread``
READ = '''columns=[c for c in pf.schema_arrow.names if c != "temperature_c" and not c.startswith("pose_")]'''
FLOOR = BASELINE.replace('columns=["hole_id", *sum(sets, [])]', READ).replace(
    '''    t = pa.table(cols)
    if writer is None:
        writer = pq.ParquetWriter(out, t.schema)''',
    '''    n = len(cols["normal_x"])
    for k in ("angle_deg", "U95_angle_deg", "angle_after_deg", "U95_after_deg", "fit_residual_um",
              "fit_residual_after_um"):
        cols[k] = cols["normal_x"]
    cols["sensors_used"] = pa.array(np.full(n, "L1 L2 L3 L4", dtype=object), pa.string())
    cols["status"] = pa.array(np.full(n, "fails", dtype=object), pa.string())
    cols["reason"] = pa.array(["as measured: angle - U95 > tolerance"], pa.string()).take(np.zeros(n, np.int8))
    for k in ("time", "cell", "panel"):
        cols[k] = b.column(k)
    t = pa.table(cols)
    if writer is None:
        text = [f.name for f in t.schema if pa.types.is_string(f.type) and f.name != "hole_id"]
        comp = {f.name: "none" if pa.types.is_floating(f.type) or f.name == "time" else "zstd" for f in t.schema}
        writer = pq.ParquetWriter(out, t.schema, compression=comp, use_dictionary=text,
                                  column_encoding={"time": "DELTA_BINARY_PACKED"},
                                  write_statistics=["time", "cell", "panel", "status"])''')


def cpu(cmd) -> float:
    r = subprocess.run([sys.executable, "-c", RUN, *cmd], capture_output=True, text=True, check=True, env=_ENV)
    return float(r.stdout.split()[3])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("log")
    ap.add_argument("layout")
    ap.add_argument("--repeat", type=int, default=4)
    a = ap.parse_args()
    assert FLOOR != BASELINE
    with tempfile.TemporaryDirectory() as d:
        out = str(Path(d) / "out.parquet")
        cmds = {"baseline": [sys.executable, "-c", BASELINE, a.log, a.layout, out],
                "floor": [sys.executable, "-c", FLOOR, a.log, a.layout, out]}
        for c in cmds.values():
            cpu(c)  # a warm-up
        ratios = []
        print("| round | baseline [s] | contract floor [s] | floor / baseline |\n|---|---|---|---|")
        for k in range(a.repeat):
            t = {name: cpu(c) for name, c in cmds.items()}
            ratios.append(t["floor"] / t["baseline"])
            print(f"| {k + 1} | {t['baseline']:.2f} | {t['floor']:.2f} | {ratios[-1]:.2f} |")
        print(f"median {np.median(ratios):.2f}")


if __name__ == "__main__":
    main()

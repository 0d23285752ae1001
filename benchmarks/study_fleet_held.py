"""The drift watch's chain against the measuring on a LocalCluster of 2 workers: one cell's 32 partitions of 4000
holes (the scenario of tests/measure/test_fleet.py::test_each_partitions_drift_watch_link_follows_its_measuring_so_
the_feeds_held_stay_bounded), measured twice on one cluster (the first run warms the workers); prints, for the
second, the wall time and, as each partition's measuring starts, how many partitions were measured and not yet
watched (their feeds held on the workers).

    python benchmarks/study_fleet_held.py [-v]     # -v: each task's worker and its start-stop (s)

Run it under the load it is about (e.g. four `python -c "while True: pass"` beside it on 2 cores).
"""

import sys
import tempfile
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.measure.helpers import calibrated_layout, hole_log  # noqa: E402


def main(n_parts: int = 32, rows: int = 4000) -> None:
    from distributed import get_task_stream

    from metrology.io.holelog import open_log
    from metrology.io.holeout import PartitionedOutput
    from metrology.measure.fleet import DaskEngine, connect
    from metrology.measure.holes import Settings
    from metrology.measure.run import measure_log

    tmp = Path(tempfile.mkdtemp(prefix="fleet_held_"))
    lay = calibrated_layout()
    cols, _, _ = hole_log(lay, n=n_parts * rows, seed=4, angle_deg=(1, 4))
    t = pa.table(cols).drop_columns(["cell"])
    for k in range(n_parts):
        d = tmp / "log" / "cell=C1" / f"part={k:02d}"
        d.mkdir(parents=True)
        pq.write_table(t.slice(rows * k, rows), d / "part-0.parquet")
    log = open_log(tmp / "log", lay.names)
    with connect(workers=2) as client:
        for name in ("warm", "dask"):
            with get_task_stream(client) as ts:
                out = PartitionedOutput(tmp / name, {})
                t0 = time.perf_counter()
                measure_log(log, lay, Settings(), DaskEngine(client), output=out)
                out.release()
                wall = time.perf_counter() - t0
    span, who = {}, {}
    for task in ts.data:
        kind, i = task["key"].split("-")[1:3]
        run = [s for s in task["startstops"] if s["action"] == "compute"][-1]
        span[kind, int(i)] = (run["start"], run["stop"])
        who[kind, int(i)] = task["worker"]
    held = [sum(span["measure", j][1] <= span["measure", i][0] < span["watch", j][0] for j in range(n_parts))
            for i in range(n_parts)]
    print(f"wall {wall:.1f} s; held {held}; max {max(held)}, in the second half {max(held[n_parts // 2:])}")
    if "-v" in sys.argv:
        t00 = min(s for s, _ in span.values())
        for i in range(n_parts):
            (a, b), (c, d) = span["measure", i], span["watch", i]
            print(f"{i:2d} measure {who['measure', i]} {a - t00:.2f}-{b - t00:.2f}  watch {who['watch', i]} "
                  f"{c - t00:.2f}-{d - t00:.2f}")


if __name__ == "__main__":
    main()

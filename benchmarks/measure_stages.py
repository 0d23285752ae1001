"""Where the per-hole CPU of ``metro measure`` goes, in process and warm (no imports, no CLI): each batch of a log
read as ``metro measure`` reads it (``metrology.io.holelog``), measured (``measure_batch``), counted into the summary
(``FleetSummary.add``) and into the drift watch's feed (``Feed.of``); CPU seconds (``time.process_time``) by stage,
``--repeat`` passes after one to warm up. With ``--panel``/``--points`` each hole's local surface is known
(``metrology.jobs.measure_panel.hole_surfaces``, built once and timed apart, its imports included).

    python benchmarks/measure_stages.py LOG.parquet LAYOUT.toml [--tolerance-deg 0.5] [--panel P --points H] [--repeat 2]

The whole-process ratios are ``measure_rounds.py``'s; this splits the per-hole part of them (the output file's
write is ``measure_io_floor.py``'s).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main():
    from metrology.io.holelog import open_log
    from metrology.io.layout import load_layout
    from metrology.jobs.measure_panel import hole_surfaces
    from metrology.measure.holes import Settings, measure_batch
    from metrology.measure.run import Feed, tune_allocator
    from metrology.measure.summary import FleetSummary

    ap = argparse.ArgumentParser()
    ap.add_argument("log"); ap.add_argument("layout")
    ap.add_argument("--tolerance-deg", type=float, default=0.5)
    ap.add_argument("--panel"); ap.add_argument("--points")
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    tune_allocator()
    clock = time.process_time
    layout = load_layout(a.layout)
    log = open_log(a.log, layout.names)
    surfaces = None
    if a.points:
        t0 = clock()
        surfaces = hole_surfaces(layout, a.panel, a.points, 0.5, 0.0, None, None, log)
        print(f"hole_surfaces (once, its imports included): {clock() - t0:.2f} s")
    settings = Settings(tolerance=float(np.radians(a.tolerance_deg)), surfaces=surfaces)
    for k in range(a.repeat + 1):
        spent = dict(measure_batch=0.0, summary=0.0, feed=0.0)
        t0 = clock()
        for part in log.partitions:
            for table, first in log.batches(part):
                t1 = clock()
                batch = measure_batch(layout, table, settings)
                t2 = clock()
                FleetSummary(a.tolerance_deg).add(batch)
                t3 = clock()
                Feed.of(batch, log, part, first)
                t4 = clock()
                spent["measure_batch"] += t2 - t1
                spent["summary"] += t3 - t2
                spent["feed"] += t4 - t3
        total = clock() - t0
        if k:  # the first pass warms up
            print(f"pass {k}: total {total:.2f} s; " + ", ".join(f"{n} {v:.2f}" for n, v in spent.items())
                  + f", reading and the rest {total - sum(spent.values()):.2f}", flush=True)


if __name__ == "__main__":
    main()

"""CPU of ``measure_batch`` with the panel known on a log without the commanded pose (the spin read or bounded,
metrology/measure/spin.py) against the same log with its pose, in one process and the same run (a ratio):
Table 2, Table 6 (4 sensors) and a drawn 3-sensor ring (the convention stated), a cylinder R 50 along the panel's x,
the holes on its crest, drawn by the forward simulator (benchmarks/study_tight_radii.py ``one_log``).

    nice -n 10 python benchmarks/bench_spin_read.py --holes 8000

Prints the best of ``--repeat`` CPU times per head and checksums of the angles and U95 (equal before and after a
change that should not change the outputs). Results: benchmarks/results/tight_radii.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _one_blas_thread  # noqa: E402,F401


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--holes", type=int, default=8000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--heads", default="table2,table6,ring3")
    args = ap.parse_args(argv)
    from study_measure import calibrate_head
    from study_tight_radii import all_heads, one_log

    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.panels import make_panel

    heads = all_heads(np.random.default_rng(53))
    for name in args.heads.split(","):
        rng = np.random.default_rng([53, 1])
        nominal = heads[name]
        true = perturb_layout(rng, nominal)
        true = true.with_params(true.zero, true.direction, noise_mm=np.full(true.n, 0.005),
                                range_mm=np.tile([30.0, 70.0], (true.n, 1)))
        cal = calibrate_head(rng, nominal, true, 0.005, np.array([30.0, 70.0]), 60)
        panel = make_panel("cylinder", 50.0, axis=(1.0, 0.0, 0.0))
        ch, log, surf, logp, surfp = one_log(rng, panel, true, cal, args.holes, 2.0, pose=False, same=True)[:5]
        measure_batch(cal, log, Settings(surfaces=surf))  # warm
        ts, tp = [], []
        for _ in range(args.repeat):
            t0 = time.process_time()
            b = measure_batch(cal, log, Settings(surfaces=surf))
            ts.append(time.process_time() - t0)
            t0 = time.process_time()
            measure_batch(cal, logp, Settings(surfaces=surfp))
            tp.append(time.process_time() - t0)
        u = b.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float)
        print(f"{name}: no pose {min(ts):.2f} s CPU, with the pose {min(tp):.2f} s, ratio {min(ts) / min(tp):.2f}; "
              f"checksums: angle {np.nansum(b.angle_before):.12f} rad, U95 {np.nansum(u):.12f} deg", flush=True)


if __name__ == "__main__":
    main()

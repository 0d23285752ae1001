"""measure with an extended layout against the same layout without its terms (issue 50: <= 1.2x).

One batch of 16 384 holes of a forward-simulated log (4 sensors) measured by ``measure_batch``
with the simple layout, with a gain term, and with a gain, an incidence response and a
temperature coefficient; interleaved, the fastest of ``--repeat`` runs each (a shared machine).

    python benchmarks/bench_effects.py [--repeat 7]

``--end-to-end HOLES``: ``metro measure LOG --layout L --out OUT`` as a user runs it (a subprocess, the
log a Parquet file of ``HOLES`` holes with readings before and after, drawn for each layout from the head
it describes: its terms the forward simulator's physics, the same seed), each layout in turn, interleaved
``--repeat`` times; the ratio of each run's time to the simple layout's run next to it, the median of
those ratios (a shared machine: the load moves between rounds, not within a pair), of the wall time and of
the CPU time the process used (user + sys: what the load does not inflate), and the load average.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np


def layouts():
    from metrology.core.effects import Drift, Incidence, Scale
    from metrology.core.effects.terms import HeadTerms
    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table

    lay = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    cov = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, 4))
    simple = lay.with_params(lay.zero, lay.direction, range_mm=np.tile([30.0, 70.0], (4, 1)), covariance=cov)
    names = simple.names
    comps = (Scale((1,), [0.005], np.array([1e-4]), names), Incidence((3,), [0.02], np.array([1e-3]), names),
             Drift((2,), [0.003], np.array([1e-4]), names, variable="temp", ref=20.0))
    # a joint fit's structure: each term correlated with its own sensor's five parameters only
    rng = np.random.default_rng(0)
    cross = np.zeros((20, 3))
    for j, c in enumerate(comps):
        i = c.sensors[0]
        cross[5 * i:5 * i + 5, j] = 0.5 * np.sqrt(np.diag(cov)[5 * i:5 * i + 5] * [1e-8, 1e-6, 1e-8][j]) \
            * rng.uniform(-1, 1, 5)
    C_tt = np.diag([1e-8, 1e-6, 1e-8])
    one = HeadTerms(comps[:1], C_tt[:1, :1], cross[:, :1])
    three = HeadTerms(comps, C_tt, cross)
    return {"simple": simple, "gain": replace(simple, effects=one), "gain+incidence+tempco": replace(simple, effects=three)}


def end_to_end(lays, holes, repeat):
    """``metro measure`` of one log with each layout, interleaved: ``{name: [seconds per round]}``."""
    import os
    import resource
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    from metrology.io.layout import save_layout
    from metrology.sim.forward import LogSpec, make_panel, simulate_log
    from metrology.sim.forward.log_write import write_log_parquet_file

    from dataclasses import replace

    from metrology.sim.head_terms import properties_from_terms

    work = Path(tempfile.mkdtemp())
    for name, lay in lays.items():  # each layout measures a log of the head it describes (the same seed)
        spec = LogSpec(replace(lay, effects=None), replace(lay, effects=None), make_panel("flat"), noise_mm=0.003,
                       properties=properties_from_terms(lay))
        write_log_parquet_file(simulate_log(spec, 1, holes), work / f"{name}.log.parquet")
    metro = str(Path(sys.executable).with_name("metro"))
    times = {k: [] for k in lays}
    loads = [os.getloadavg()[0]]
    for name, lay in lays.items():
        save_layout(lay, work / f"{name}.toml")
    for r in range(repeat + 1):  # the first round warms the disk cache and the imports: not kept
        for name in lays:
            c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            done = subprocess.run([metro, "-q", "measure", str(work / f"{name}.log.parquet"), "--layout", str(work / f"{name}.toml"), "--out",
                                   str(work / f"{name}.parquet")], check=False, capture_output=True, text=True)
            if done.returncode not in (0, 1):  # 1: a verdict, not a failure
                raise SystemExit(f"metro measure with {name}: exit {done.returncode}: {done.stderr.strip()}")
            wall = time.perf_counter() - t0
            c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            if r:
                times[name].append((wall, c1.ru_utime - c0.ru_utime + c1.ru_stime - c0.ru_stime))
    loads.append(os.getloadavg()[0])
    return times, loads


def main(argv=None):
    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import LogSpec, make_panel, simulate_log
    from metrology.sim.forward.log_write import log_table

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--end-to-end", type=int, default=0, metavar="HOLES")
    args = ap.parse_args(argv)
    lays = layouts()
    if args.end_to_end:
        times, loads = end_to_end(lays, args.end_to_end, args.repeat)
        print(f"metro measure, {args.end_to_end} holes, {args.repeat} interleaved rounds, load average "
              f"{loads[0]:.1f} at the start, {loads[1]:.1f} at the end")
        base = np.array(times["simple"])
        for name, ts in times.items():
            ts = np.array(ts)
            ratio = np.median(ts / base, axis=0)
            print(f"{name:<24} wall median {np.median(ts[:, 0]):.2f} s, CPU (user + sys) median {np.median(ts[:, 1]):.2f} s;"
                  f"  median ratio to simple: wall {ratio[0]:.2f}x, CPU {ratio[1]:.2f}x")
        return
    spec = LogSpec(lays["simple"], lays["simple"], make_panel("flat"), noise_mm=0.003)
    table = log_table(next(simulate_log(spec, 1, 16384, chunk_holes=16384)))
    best = {k: np.inf for k in lays}
    for name, lay in lays.items():  # warm: imports and caches
        measure_batch(lay, table, Settings())
    for _ in range(args.repeat):
        for name, lay in lays.items():
            t0 = time.perf_counter()
            measure_batch(lay, table, Settings())
            best[name] = min(best[name], time.perf_counter() - t0)
    for name, t in best.items():
        print(f"{name:<24} {t:.3f} s  {t / best['simple']:.2f}x")


if __name__ == "__main__":
    main()

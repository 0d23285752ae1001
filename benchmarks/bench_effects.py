"""measure with an extended layout against the same layout without its terms (issue 50: <= 1.2x).

One batch of 16 384 holes of a forward-simulated log (4 sensors) measured by ``measure_batch``
with the simple layout, with a gain term, and with a gain, an incidence response and a
temperature coefficient; interleaved, the fastest of ``--repeat`` runs each (a shared machine).

    python benchmarks/bench_effects.py [--repeat 7]
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


def main(argv=None):
    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import LogSpec, make_panel, simulate_log
    from metrology.sim.forward.log_write import log_table

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)
    lays = layouts()
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

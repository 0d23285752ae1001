"""Speed of the hole-log simulator (``metro simulate-log``, issue 29): holes/s drawn, and written.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_simulate_log.py [--holes 1000000] [--repeat 3] \
        [--out benchmarks/results/simulate_log.txt]

Per panel (flat, sphere R 800 mm, cylinder R 800 mm; the Table 6 head, a calibrated layout 0.015-0.03
mm / deg from the truth): the generation alone (:func:`metrology.sim.forward.log.simulate_log`,
readings before and after the cell's adjustment and the truth, no file), best of ``--repeat``.
Baseline, same run: drawing the generator's random numbers alone (numpy's PCG64, the same counts
and block size), so the ratio says what the geometry costs on top of the draws. Then the writes of
the flat log: one CSV (log + truth CSV) and partitioned Parquet (log + truth Parquet).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from metrology.io.data import data_path  # noqa: E402
from metrology.io.layout import load_layout  # noqa: E402
from metrology.sim.forward.head import perturb_layout  # noqa: E402
from metrology.sim.forward.log import BLOCK_HOLES, simulate_log  # noqa: E402
from metrology.sim.forward.log_spec import LogSpec  # noqa: E402
from metrology.sim.forward.log_write import write_log_csv, write_log_parquet  # noqa: E402
from metrology.sim.forward.panels import make_panel  # noqa: E402


def draws_only(holes, n_sensors):
    """The random numbers a clean log draws, block by block, nothing else."""
    for b in range(-(-holes // BLOCK_HOLES)):
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(0, spawn_key=(0, b))))
        h = BLOCK_HOLES
        rng.uniform(size=h), rng.uniform(size=h), rng.uniform(size=h), rng.uniform(size=h), rng.random(h)
        rng.standard_normal(h)
        rng.standard_normal((h, n_sensors), dtype=np.float32), rng.standard_normal((h, n_sensors), dtype=np.float32)


def best(fn, repeat):
    """Best wall time and best CPU time of this process (s) over ``repeat`` runs."""
    wall, cpu = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return min(wall), min(cpu)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--holes", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    lay = load_layout(data_path("measured", "nominal.toml"))
    true = perturb_layout(np.random.default_rng(1), lay, (0.015, 0.03), (0.015, 0.03))
    lines = [f"# {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; {a.holes} holes, "
             f"best of {a.repeat}; numpy {np.__version__}; "
             f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}",
             "# wall time counts other processes' load; CPU time is this process's own (all its threads)"]
    t_base, c_base = best(lambda: draws_only(a.holes, lay.n), a.repeat)
    lines.append(f"baseline (random draws only): {t_base:.3f} s, {a.holes / t_base:,.0f} holes/s; "
                 f"CPU {c_base:.3f} s")
    for kind in ("flat", "sphere", "cylinder"):
        spec = LogSpec(true, lay, make_panel(kind, 800.0))
        t, c = best(lambda: sum(c.n for c in simulate_log(spec, 0, a.holes, 1, chunk_holes=8 * BLOCK_HOLES)), a.repeat)
        lines.append(f"generate {kind:8s}: {t:.3f} s, {a.holes / t:,.0f} holes/s, {t / t_base:.2f}x the baseline; "
                     f"CPU {c:.3f} s, {a.holes / c:,.0f} holes per CPU-s")
    spec = LogSpec(true, lay, make_panel("flat"))
    with tempfile.TemporaryDirectory() as d:
        t = time.perf_counter()
        write_log_csv(simulate_log(spec, 0, a.holes, 1, 8 * BLOCK_HOLES), Path(d, "log.csv"), Path(d, "truth.csv"))
        t_csv = time.perf_counter() - t
        size = Path(d, "log.csv").stat().st_size
        lines.append(f"generate + write CSV (log + truth): {t_csv:.3f} s, {a.holes / t_csv:,.0f} holes/s "
                     f"(log {size / 1e6:.0f} MB)")
        t = time.perf_counter()
        _, files = write_log_parquet(simulate_log(spec, 0, a.holes, 1, 8 * BLOCK_HOLES), Path(d, "logs"),
                                     Path(d, "truth.parquet"))
        t_pq = time.perf_counter() - t
        size = sum(f.stat().st_size for f in files)
        lines.append(f"generate + write partitioned Parquet (log + truth): {t_pq:.3f} s, {a.holes / t_pq:,.0f} "
                     f"holes/s ({len(files)} files, {size / 1e6:.0f} MB)")
    text = "\n".join(lines)
    print(text)
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text + "\n")


if __name__ == "__main__":
    main()

"""Does the drift watch of `metro measure` flag a knocked sensor and a slow drift, and stay quiet in
control? On hole logs drawn by the independent forward simulator (metrology/sim/forward/log: beams
cast at the panel, the cell's own adjustment), measured by the same code as `metro measure`:

- **in control**: ``--control`` holes a cell with nothing wrong: alarms against the stated rate
  (one per ARL0 = 1e6 holes a cell);
- **shift** (a knocked sensor): the zero of a random sensor jumps by ``m`` times its detectable
  size at a random hole; the holes from the jump to the alarm;
- **drift**: the zero of a random sensor grows linearly, reaching ``m`` times its detectable size
  after ``--drift-holes`` holes; the holes from the drift's start to the alarm, and the drift's size
  then (in detectable sizes). A CUSUM sums: a drift is often flagged before it reaches one
  detectable size.

The detectable size of sensor k is the zero shift that moves the redundant residual by one chart
scale (DETECTABLE_SCALES): ``scale / |signature_k|``, read off the chart's own baseline.

    python benchmarks/study_drift.py --trials 40 --control 1000000 --seed 1 --json out.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import _one_blas_thread  # noqa: E402,F401


def setup(rng, panel_kind="flat", radius=None):
    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.panels import make_panel

    nominal = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    nominal = nominal.with_params(nominal.zero, nominal.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    true = perturb_layout(rng, nominal, zero_error_mm=(0.002, 0.01), direction_error_deg=(0.001, 0.01))
    C = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, 4))
    cal = nominal.with_params(nominal.zero, nominal.direction, covariance=C)
    panel = make_panel(panel_kind, radius) if radius else make_panel(panel_kind)
    return true, cal, panel


def watch_log(spec, seed, holes, chunk=1 << 16):
    """Measure a forward-simulated log the way `metro measure` does; the Watch after it."""
    from metrology.measure.holes import Settings, measure_batch
    from metrology.measure.run import Feed, Watch
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_write import log_table
    from metrology.io.holelog import batch_of

    watch = Watch(spec.cell_layout.names)
    for c in simulate_cell(spec, seed, 0, holes, chunk_holes=chunk):
        t = batch_of(log_table(c), spec.cell_layout.names)
        b = measure_batch(spec.cell_layout, t, Settings(min_radius_mm=np.inf))
        watch.feed(Feed.of(b, "sim", first_row=int(c.hole[0])))
    watch.finish()
    return watch


def hole_of(alarm_id: str) -> int:
    return int(alarm_id.rsplit("-", 1)[1])


def run(args):
    from dataclasses import replace

    from metrology.sim.forward.log_spec import LogSpec, SensorDrift, SensorShift

    rng = np.random.default_rng(args.seed)
    out = {"args": vars(args)}
    true, cal, panel = setup(rng)
    base = LogSpec(true_layout=true, cell_layout=cal, panel=panel)
    # the chart's scale and signature on this head: a pilot log
    pilot = watch_log(base, 0, 2000)
    ch = pilot.charts["C1"]
    det = {s: float(ch.scale / abs(g)) for s, g in zip(cal.names, ch.signature)}
    out["detectable_mm"] = det
    out["scale_um"] = ch.scale * 1e3
    print(f"chart scale {ch.scale * 1e3:.2f} um; detectable zero shift per sensor (um): "
          + ", ".join(f"{k} {v * 1e3:.1f}" for k, v in det.items()), flush=True)
    t0 = time.perf_counter()
    w = watch_log(base, 1, int(args.control))
    n_alarms = len(w.alarms)
    out["control"] = {"holes": int(args.control), "alarms": n_alarms, "expected": args.control / 1e6,
                      "seconds": time.perf_counter() - t0}
    print(f"in control: {n_alarms} alarm(s) in {int(args.control):,} holes (stated rate: 1 per 1,000,000)", flush=True)
    for kind in ("shift", "drift"):
        for mult in (1.0, 2.0):
            delays, missed, early, sizes = [], 0, 0, []
            for trial in range(args.trials):
                s = str(rng.choice(cal.names))
                k0 = int(rng.integers(1000, 3000))
                sign = float(rng.choice([-1.0, 1.0]))
                size = sign * mult * det[s]
                if kind == "shift":
                    spec = replace(base, shifts=(SensorShift(s, size, k0),))
                    reach = k0
                    holes = k0 + 2000
                else:
                    rate = size / args.drift_holes  # reaches mult x detectable after drift_holes holes
                    spec = replace(base, drifts=(SensorDrift(s, rate, per="hole", start_hole=k0),))
                    reach = k0 + int(np.ceil(det[s] / abs(rate)))  # where it reaches the detectable size
                    holes = k0 + 3 * args.drift_holes
                w = watch_log(spec, 100 + trial, holes)
                after = [hole_of(a.hole_id) - 1 for a in w.alarms if hole_of(a.hole_id) - 1 >= k0]
                early += sum(hole_of(a.hole_id) - 1 < k0 for a in w.alarms)
                if not after:
                    missed += 1
                    continue
                delays.append(after[0] - (k0 if kind == "drift" else reach))
                if kind == "drift":
                    sizes.append((after[0] - k0) * abs(rate) / det[s])
            d = np.array(delays)
            row = {"kind": kind, "size_x_detectable": mult, "trials": args.trials, "missed": missed,
                   "alarms_before_the_change": early,
                   "delay_holes_median": float(np.median(d)) if d.size else None,
                   "delay_holes_p95": float(np.quantile(d, 0.95)) if d.size else None,
                   "delay_holes_max": int(d.max()) if d.size else None,
                   "delay_from": "the shift" if kind == "shift" else "the drift's start",
                   "size_at_alarm_x_detectable_median": float(np.median(sizes)) if sizes else None}
            out[f"{kind}_x{mult:g}"] = row
            size = row["size_at_alarm_x_detectable_median"]
            print(f"| {kind} | {mult:g} x detectable | {args.trials - missed}/{args.trials} | "
                  f"{row['delay_holes_median']:.0f} | {row['delay_holes_p95']:.0f} | {row['delay_holes_max']} | "
                  f"{'-' if size is None else format(size, '.2f')} | {early} |", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--control", type=float, default=1e6, help="in-control holes")
    ap.add_argument("--drift-holes", type=int, default=2000, help="holes a drift takes to reach its size")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    print("| change | size | flagged | holes to the alarm: median | p95 | max | drift at the alarm (x detectable) "
          "| alarms before the change |")
    print("|---|---|---|---|---|---|---|---|")
    out = run(args)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()

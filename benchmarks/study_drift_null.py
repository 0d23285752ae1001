"""Does the drift watch keep its design false-alarm rate on curved panels? Null logs (no drift, no
knock) of the independent forward simulator (metrology/sim/forward/log), measured as `metro measure`
measures them, charted by metrology.measure.chart.CusumChart with its own baseline per log.

Per panel (flat; sphere R 500; cylinder R 500, axis at a random azimuth per log; the generated wing
drilled from its bundled hole table, cycled) and ``--logs`` logs of ``--holes`` holes, each with its
own seed and a Table 6 head with its own small calibration error: the alarms per charted hole at the
chart's decision interval ``h`` (ARL0 1e6 holes) and at the intervals of ARL0 1e3 and 1e4 holes
(``cusum_h``), where a few logs hold enough alarms to check the design: if the residual stream is as
the chart assumes (independent, its level and scale those of the baseline), the measured ARL matches
the design at every ``h``. The interval is the Poisson 95 % one of the alarm count.

    nice -n 10 python benchmarks/study_drift_null.py --logs 40 --holes 20000 --seed 1 --json out.json
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

PANELS = ("flat", "sphere R 500", "cylinder R 500", "wing (hole table)")
ARLS = (1e3, 1e4, 1e6)


def _spec(rng, label):
    from metrology.core.paper import TABLE6_NOMINAL, layout_from_table
    from metrology.io.data import data_path
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.holes import read_hole_table
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.panels import make_panel
    from metrology.sim.forward.shapes import generated_panel

    nominal = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    nominal = nominal.with_params(nominal.zero, nominal.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    true = perturb_layout(rng, nominal, zero_error_mm=(0.002, 0.01), direction_error_deg=(0.001, 0.01))
    cov = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, 4))
    cal = nominal.with_params(nominal.zero, nominal.direction, covariance=cov)
    if label.startswith("wing"):
        return LogSpec(true_layout=true, cell_layout=cal, panel=generated_panel("wing"),
                       table=read_hole_table(data_path("panels", "wing.holes.csv")))
    kind = label.split()[0]
    a = rng.uniform(0, np.pi)
    panel = make_panel(kind) if kind == "flat" else make_panel(kind, 500.0, axis=(np.cos(a), np.sin(a), 0.0))
    return LogSpec(true_layout=true, cell_layout=cal, panel=panel)


def _residuals(spec, seed, holes):
    """The chart's inputs of one simulated log: ``(hole ids, rho mm, noise sd mm, signature)``."""
    from metrology.io.holelog import batch_of
    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_write import log_table

    out = []
    for c in simulate_cell(spec, seed, 0, holes, chunk_holes=holes):
        b = measure_batch(spec.cell_layout, batch_of(log_table(c), spec.cell_layout.names), Settings())
        ids = np.asarray(log_table(c).column("hole_id").to_pylist(), dtype=object)[b.chart["index"]]
        out.append((ids, b.chart["rho_mm"], b.chart["noise_sd_mm"], b.chart["signature"]))
    return tuple(np.concatenate([o[i] for o in out]) for i in range(4))


def run(args):
    from scipy.stats import chi2

    from metrology.measure.chart import CUSUM_H, CusumChart, cusum_h

    hs = {arl: (CUSUM_H if arl == 1e6 else cusum_h(arl)) for arl in ARLS}
    rng = np.random.default_rng(args.seed)
    rows = []
    for label in args.panels:
        t0 = time.perf_counter()
        alarms = {arl: 0 for arl in ARLS}
        charted = {arl: 0 for arl in ARLS}
        persisted = 0
        for i in range(args.logs):
            spec = _spec(rng, label)
            ids, rho, sd, sig = _residuals(spec, int(rng.integers(2**31)), args.holes)
            for arl, h in hs.items():
                ch = CusumChart("C1", tuple(spec.cell_layout.names), h=h, keep=8)
                ch.update(ids, np.arange(rho.size, dtype=float), np.full(rho.size, "P"), rho, sd, sig)
                ch.finish()
                alarms[arl] += len(ch.alarms)
                charted[arl] += ch.charted
                if arl == 1e6:
                    persisted += sum(a.persisted for a in ch.alarms)
        for arl in ARLS:
            n, m = alarms[arl], charted[arl]
            lo = chi2.ppf(0.025, 2 * n) / 2 if n else 0.0
            hi = chi2.ppf(0.975, 2 * n + 2) / 2
            row = {"panel": label, "design_arl_holes": arl, "h": hs[arl], "logs": args.logs, "charted_holes": m,
                   "alarms": n, "expected_alarms": m / arl, "expected_alarms_95": [lo, hi],
                   "measured_arl_holes": (m / n) if n else None,
                   "seconds": round(time.perf_counter() - t0, 1)}
            if arl == 1e6:
                row["alarms_persisted"] = persisted
            rows.append(row)
            print(f"| {label} | {arl:.0e} | {hs[arl]:.3f} | {m:,} | {n} [{lo:.1f}, {hi:.1f}] | {m / arl:.1f} | "
                  f"{'-' if not n else format(m / n, '.3g')} |", flush=True)
    return {"args": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(args).items() if k != "json"},
            "rows": rows}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=40)
    ap.add_argument("--holes", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--panels", default=",".join(PANELS))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    args.panels = tuple(args.panels.split(","))
    print("| panel | design ARL [holes] | h | charted holes | alarms [95 % interval] | expected at the design | "
          "measured ARL [holes] |")
    print("|---|---|---|---|---|---|---|")
    out = run(args)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

"""False verdicts from gross readings without a panel (issue 51 item 5), on the independent forward simulator.

Per head (the paper's Table 6, 4 sensors; its first three sensors, a 3-sensor head), panel (flat; sphere and
cylinder of R 500 and R 1000 mm, the cylinders' axes at random azimuths, one per group of holes) and gross
model, holes drawn by ``metrology.sim.forward.log.simulate_cell`` (beams cast at the panel, the cell's
micro-plane adjustment in the loop, after-readings) and measured by ``metrology.measure.holes.measure_batch``
without a panel (``--min-radius-mm`` 500, the default; and inf on the flat panel). Gross models:

- ``none``: a clean log;
- ``indep 0.01``, ``indep 0.05``: each reading gross with that probability (+-U(0.2, 2) mm), before and after
  drawn independently (``LogSpec.gross_rate``);
- ``persistent``: one sensor offset by the same amount before and after (a burr or a sealant dot under its
  spot): per group of holes one sensor and one size, +-U(0.05, 1.0) mm (``SensorShift`` from hole 0).

Counted against the truth (the simulator's true angle after the adjustment; tolerance 0.5 deg): false
``fails`` (drilled within tolerance), false ``conforms`` (drilled out of it), ``undecided``, ``not_measured``,
and U95 coverage of the judged angle (``|judged - true| <= U95``) on the judged holes.

    nice -n 10 python benchmarks/study_gross_item5.py --holes 4000 --groups 40 --seed 5 --json out.json
        [--tolerance-deg 1] [--sensors 4]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import _one_blas_thread  # noqa: E402,F401

from metrology.core.paper import TABLE6_NOMINAL, layout_from_table  # noqa: E402
from metrology.io.holelog import batch_of  # noqa: E402
from metrology.measure.batch import STATUSES  # noqa: E402
from metrology.measure.holes import Settings, measure_batch  # noqa: E402
from metrology.sim.forward import perturb_layout  # noqa: E402
from metrology.sim.forward.log import simulate_cell  # noqa: E402
from metrology.sim.forward.log_spec import LogSpec, SensorShift  # noqa: E402
from metrology.sim.forward.log_write import log_table  # noqa: E402
from metrology.sim.forward.panels import make_panel  # noqa: E402

TOL = np.radians(0.5)  # --tolerance-deg
PANELS = [("flat", None), ("sphere", 500.0), ("cylinder", 500.0), ("sphere", 1000.0), ("cylinder", 1000.0)]
GROSS = ["none", "indep 0.01", "indep 0.05", "persistent"]


def head(rng, sensors):
    nominal = layout_from_table(TABLE6_NOMINAL, noise_mm=0.003)
    nominal = nominal.with_params(nominal.zero, nominal.direction, range_mm=np.tile([30.0, 70.0], (4, 1)))
    if sensors == 3:
        nominal = nominal.subset(list(nominal.names[:3]))
    true = perturb_layout(rng, nominal, zero_error_mm=(0.002, 0.01), direction_error_deg=(0.001, 0.01))
    cov = np.diag(np.tile([0.005 ** 2] * 3 + [np.radians(0.01) ** 2] * 2, nominal.n))
    return true, nominal.with_params(nominal.zero, nominal.direction, covariance=cov)


def run(sensors, panel, radius, gross, R, holes, groups, seed):
    rng = np.random.default_rng([seed, sensors, PANELS.index((panel, radius)), GROSS.index(gross)])
    true, cell = head(rng, sensors)
    counts = dict.fromkeys(["holes", *STATUSES, "false_fails", "false_conforms", "judged", "covered"], 0)
    per = holes // groups
    for g in range(groups):
        phi = rng.uniform(0, np.pi)
        pan = make_panel(panel, radius, axis=(np.cos(phi), np.sin(phi), 0.0)) if panel == "cylinder" else \
            make_panel(panel, radius)
        spec = LogSpec(true_layout=true, cell_layout=cell, panel=pan)
        if gross.startswith("indep"):
            spec = replace(spec, gross_rate=float(gross.split()[1]))
        elif gross == "persistent":
            k = int(rng.integers(sensors))
            spec = replace(spec, shifts=(SensorShift(true.names[k], float(rng.choice([-1, 1]) * rng.uniform(0.05, 1.0)), 0),))
        (chunk,) = list(simulate_cell(spec, int(rng.integers(2 ** 31)), 0, per, chunk_holes=per))
        b = measure_batch(cell, batch_of(log_table(chunk), cell.names), Settings(tolerance=TOL, min_radius_mm=R))
        status = np.array(STATUSES)[b.status]
        good = chunk.true_after <= TOL
        counts["holes"] += per
        for s in STATUSES:
            counts[s] += int((status == s).sum())
        counts["false_fails"] += int(((status == "fails") & good).sum())
        counts["false_conforms"] += int(((status == "conforms") & ~good).sum())
        judged = np.isin(status, ["conforms", "fails", "undecided"])
        counts["judged"] += int(judged.sum())
        counts["covered"] += int((np.abs(b.judged - chunk.true_after) <= b.judged_u95)[judged].sum())
    return counts


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--holes", type=int, default=2000)
    ap.add_argument("--groups", type=int, default=40)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--tolerance-deg", type=float, default=0.5)
    ap.add_argument("--sensors", default="4,3", help="heads: 4 (Table 6), 3 (its first three sensors)")
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    global TOL
    TOL = np.radians(a.tolerance_deg)
    rows = []
    t0 = time.perf_counter()
    print("| head | panel | gross | R bound | holes | conforms | fails | undecided | not_measured | false fails | "
          "false conforms | U95 coverage % |\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    for sensors in [int(x) for x in a.sensors.split(",")]:
        for panel, radius in PANELS:
            for gross in GROSS:
                for R in ((500.0, np.inf) if panel == "flat" else (500.0,)):
                    c = run(sensors, panel, radius, gross, R, a.holes, a.groups, a.seed)
                    rows.append({"sensors": sensors, "panel": panel, "radius_mm": radius, "gross": gross,
                                 "min_radius_mm": R, **c})
                    name = panel if radius is None else f"{panel} R {radius:g}"
                    cov = 100.0 * c["covered"] / max(c["judged"], 1)
                    print(f"| {sensors} | {name} | {gross} | {R:g} | {c['holes']} | {c['conforms']} | {c['fails']} | "
                          f"{c['undecided']} | {c['not_measured']} | {c['false_fails']} | {c['false_conforms']} | "
                          f"{cov:.1f} |", flush=True)
    print(f"({time.perf_counter() - t0:.0f} s)")
    if a.json:
        Path(a.json).write_text(json.dumps({"args": vars(a), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()

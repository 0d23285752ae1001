"""Does ``diagnose`` name an incidence bias on planned poses more often than on random ones?

Per seed (independent forward simulator): a table6-like head with its true layout, a random flat
plate and its scan, 40 planned poses (``metro plan``) and 40 random poses of the paper's kind
under the same limits (the first feasible candidates); one incidence bias (``draw_incidence``,
size ``--size-mm`` at the largest incidence either pose set reaches) on one sensor, the same
function for both sets; noise 5 um. ``diagnose`` runs on each; reported: how often it names
incidence on the right sensor, and what else it names.

    nice -n 10 python benchmarks/study_plan_diagnose.py [--seeds 8] [--first-seed 0] [--poses 40] [--size-mm 0.08]
        [--separate incidence] [--tilt-max-deg 10]

``--separate incidence`` plans with the incidence coefficient and the sensor's characteristic
(gain, bow, S-shape) in the D-criterion (:func:`metrology.plan.plan.design_columns`).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from metrology.calibration.dataset import Dataset
from metrology.core.frames import quaternion_from_matrix
from metrology.diagnosis.decide import diagnose
from metrology.io.export import TrackerExport
from metrology.plan import draw_candidates, feasible, plan_poses
from metrology.sim.forward import cast_beams, draw_incidence

from study_plan import scene


def _named(res):
    causes = res.get("causes")
    if causes:
        return [(c["cause"], tuple(c.get("sensors") or ())) for c in causes]
    return [] if res["cause"] in ("none", "unexplained") else [(res["cause"], tuple(res.get("sensors") or ()))]


def trial(seed, n_poses, noise, size, kind, separate=(), tilt_deg=10.0):
    rng = np.random.default_rng([seed, 7])
    nominal, true, surface, cloud, plane, extent, limits = scene(kind, rng, noise, tilt_deg)
    planned = plan_poses(nominal, plane, extent, n_poses, limits, nominal.noise_mm, rng, robustness_trials=0,
                         separate=separate).planned.poses
    cands = draw_candidates(rng, nominal, plane, extent, 3000, limits)
    rand = cands.select(np.flatnonzero(feasible(nominal, plane, extent, cands, limits))[:n_poses])
    hits = {lab: cast_beams(surface, true.zero, true.direction, p.rot, p.trans)
            for lab, p in (("planned", planned), ("random", rand))}
    sensor = int(rng.integers(nominal.n))
    amax = max(float(np.nanmax(h.incidence[:, sensor])) for h in hits.values())
    bias = draw_incidence(rng, amax, size)
    out = {}
    for lab, p in (("planned", planned), ("random", rand)):
        d = hits[lab].d.copy()
        d[:, sensor] += bias(hits[lab].incidence[:, sensor])
        d += rng.normal(scale=noise, size=d.shape)
        nan = np.full(len(p), np.nan)
        export = TrackerExport(tuple(f"P{k + 1:03d}" for k in range(len(p))), nan, nan, quaternion_from_matrix(p.rot),
                               p.trans, nominal.names, d)
        res = diagnose(Dataset(export, nominal, plane, cloud)).to_dict()
        named = _named(res)
        out[lab] = (any(c == "incidence" and set(s) == {nominal.names[sensor]} for c, s in named), named)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--poses", type=int, default=40)
    ap.add_argument("--size-mm", type=float, default=0.08)
    ap.add_argument("--noise-mm", type=float, default=0.005)
    ap.add_argument("--kind", default="table6")
    ap.add_argument("--tilt-max-deg", type=float, default=10.0)
    ap.add_argument("--separate", default="", help="passed to the plan (comma-separated): incidence, scale, nonlinearity")
    args = ap.parse_args()
    t0 = time.process_time()
    sep = tuple(filter(None, args.separate.split(",")))
    res = [trial(s, args.poses, args.noise_mm, args.size_mm, args.kind, sep, args.tilt_max_deg)
           for s in range(args.first_seed, args.first_seed + args.seeds)]
    for lab in ("planned", "random"):
        right = sum(r[lab][0] for r in res)
        other = Counter(c for r in res for c, _ in r[lab][1] if c != "incidence")
        print(f"{lab:8}: incidence named on the right sensor {right}/{len(res)}; other causes named: {dict(other) or 'none'}")
    print(f"plan --separate {args.separate or '(none)'}; {args.kind}, {args.poses} poses, incidence {args.size_mm} mm, "
          f"noise {args.noise_mm} mm, tilt <= {args.tilt_max_deg:g} deg; "
          f"CPU {time.process_time() - t0:.0f} s")


if __name__ == "__main__":
    main()

"""False-alarm rate and detectable range of `metro diagnose`, over seeded trials.

For the typical pose set (metro's PoseSpec: stand-off 40-60 mm, tilt <= 5 deg, spots over
200 mm; 80 poses, 3 um noise, the paper's Table 6 foot and Table 5 datum):

* null runs: the fraction named anything but ``none`` (the false-alarm rate);
* each catalogued effect at a ladder of sizes on a sensor drawn per trial: the fraction
  with the right cause (and sensor);
* the out-of-catalogue periodic error: the fraction named as a catalogued cause with
  confidence ``high``;
* for ``plane_form``, a tracker scan of the same surface is given as the datum cloud: the
  fraction in which the readings' form agrees with the cloud's (1 % false disagreement by
  construction).

The detectable range of an effect is the sizes at which the right cause is named in at least
90 % of the trials. ``--wide`` repeats with a wider pose set (stand-off 34-66 mm, tilt <= 10
deg) to show what poses separate scale and incidence from the geometry.

    python benchmarks/study_diagnose.py [--trials 10] [--null 100] [--poses 80] [--folds 5] [--wide] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from multiprocessing import Pool

import _one_blas_thread  # noqa: F401  (first: one BLAS thread a job; same directory)
import numpy as np

SIZES = {
    "scale": [2e-3, 3e-3, 4e-3, 6e-3, 8e-3, 1.6e-2],
    "incidence": [0.05, 0.1, 0.2, 0.4],
    "drift": [0.001, 0.002, 0.004, 0.008, 0.03],
    "nonlinearity": [0.01, 0.02, 0.04, 0.08, 0.3],
    "plane_form": [0.001, 0.002, 0.004, 0.008, 0.05],
    "pose_error": [0.001, 0.002, 0.003, 0.004, 0.006, 0.03],
    "outliers": [0.015, 0.02, 0.03, 0.06, 1.0],
    "periodic": [0.003, 0.006, 0.012, 0.024],
}


def trial(args):
    """One seeded run: (effect, size, seed, n_poses, wide) -> dict with the verdict."""
    from metrology.calibration.dataset import Dataset, check
    from metrology.diagnosis import diagnose
    from metrology.core.paper import TABLE5_PLANE
    from metrology.core.plane import Plane
    from metrology.sim.simulation import PoseSpec
    from metrology.sim.synth import SETUP_EFFECTS, HiddenEffect, synth_cloud, synth_run, typical_layouts

    effect, size, seed, n_poses, wide, folds = args
    rng = np.random.default_rng([seed, list(SIZES).index(effect) + 1 if effect in SIZES else 0, int(round(size * 1e6))])
    nominal, true = typical_layouts(range_mm=(20.0, 80.0) if wide else (30.0, 70.0))
    plane = Plane(TABLE5_PLANE[:3], TABLE5_PLANE[3])
    spec = PoseSpec(standoff_mm=(34.0, 66.0), tilt_max=np.deg2rad(10.0)) if wide else PoseSpec()
    sensor = None
    hidden = []
    if effect != "null":
        sensor = None if effect in SETUP_EFFECTS else nominal.names[int(rng.integers(nominal.n))]
        hidden = [HiddenEffect(effect, sensor, size)]
    export, truth = synth_run(rng, true, plane, n_poses, hidden, spec)
    # a datum form comes with a tracker scan of the same surface: the cross-check's agreement
    points = synth_cloud(rng, plane, hidden) if effect == "plane_form" else None
    d = diagnose(Dataset(check(export, nominal), nominal, plane, points), folds=folds, sim_reps=1)
    right = (d.cause == effect) and (effect in SETUP_EFFECTS or d.sensors == [sensor])
    return {"effect": effect, "size": size, "seed": seed, "cause": d.cause, "sensors": d.sensors,
            "confidence": d.confidence, "right": bool(right) if effect != "null" else d.cause == "none",
            "catalogued_high": d.cause not in ("none", "unexplained") and d.confidence in ("high", "moderate"),
            "cloud_agrees": None if d.datum_form is None else d.datum_form.against_readings.agree}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--null", type=int, default=100)
    ap.add_argument("--poses", type=int, default=80)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--wide", action="store_true")
    ap.add_argument("--folds", type=int, default=5, help="k of the k-fold (the CLI default: 5)")
    ap.add_argument("--only", default=None, help="comma-separated effects")
    ap.add_argument("--json", default=None, help="write the raw results here")
    a = ap.parse_args(argv)
    jobs = [("null", 0.0, s, a.poses, a.wide, a.folds) for s in range(a.null)]
    effects = SIZES if a.only is None else {k: SIZES[k] for k in a.only.split(",")}
    for e, sizes in effects.items():
        jobs += [(e, z, s, a.poses, a.wide, a.folds) for z in sizes for s in range(a.trials)]
    t0 = time.time()
    with Pool(a.jobs) as pool:
        res = pool.map(trial, jobs, chunksize=1)
    dt = time.time() - t0
    null = [r for r in res if r["effect"] == "null"]
    print(f"pose set: {'wide' if a.wide else 'typical'}, {a.poses} poses, {a.folds} folds; {len(res)} diagnoses in {dt:.0f} s "
          f"({dt / max(len(res), 1) * a.jobs:.1f} s each)")
    if null:
        fa = sum(not r["right"] for r in null)
        print(f"null: {fa}/{len(null)} false alarms ({100 * fa / len(null):.1f} %): "
              + ", ".join(sorted({r['cause'] for r in null if not r['right']})))
    print(f"{'effect':14s}{'size':>10s}{'right':>8s}{'high':>7s}  verdicts")
    for e in effects:
        good = []
        for z in effects[e]:
            rs = [r for r in res if r["effect"] == e and r["size"] == z]
            right = sum(r["right"] for r in rs)
            high = sum(r["catalogued_high"] for r in rs)
            verdicts = {}
            for r in rs:
                verdicts[r["cause"]] = verdicts.get(r["cause"], 0) + 1
            agree = [r["cloud_agrees"] for r in rs if r["cloud_agrees"] is not None]
            extra = f"  datum cloud agrees {sum(agree)}/{len(agree)}" if agree else ""
            print(f"{e:14s}{z:10.4g}{right:5d}/{len(rs):<3d}{high:4d}/{len(rs):<3d} {verdicts}{extra}")
            if e != "periodic" and len(rs) and right >= 0.9 * len(rs):
                good.append(z)
        if e != "periodic":
            print(f"  detectable (>= 90 % right): {', '.join(f'{g:g}' for g in good) if good else 'none of the tested sizes'}")
    if a.json:
        from metrology.io.atomic import write_text

        write_text(a.json, json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

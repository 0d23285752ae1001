"""The filters with their state extended by a layout's terms against the joint least squares (issue 50).

Calibration runs of the forward simulator (100 poses, 4 sensors, 4 um noise, the head's temperature
swept over 18-22 deg C) of a head with a gain of -0.8 % on L2 and a zero following the temperature at
3 um/K on L3; the layout states both terms at 0 with 1 sigma 0.005 (a prior, not the answer). Per
seed and term: each method's estimate in its own stated sigma from the truth, and from least
squares' in the larger of the two sigmas; the time of each method.

    python benchmarks/study_terms_filter.py [--seeds 5 6 7 8 9 10] [--out benchmarks/results/study_terms_filter.md]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import tempfile
import time
from dataclasses import replace

import numpy as np

GAIN, RATE = -0.008, 0.003
METHODS = ("lsq", "ekf", "iekf")


def dataset(tmp, seed):
    from metrology.calibration.dataset import load_dataset
    from metrology.core.effects import Drift, Scale
    from metrology.core.effects.terms import HeadTerms
    from metrology.io.export import write_export
    from metrology.io.layout import save_layout
    from metrology.sim.forward import Characteristic, HeadProperties, SensorProperty, draw_calibration, draw_head

    props = HeadProperties((SensorProperty(1, characteristic=Characteristic("gain", 30.0, 70.0, {"gain": GAIN})),
                            SensorProperty(2, tempco_mm_per_k=RATE, ref_temp_c=20.0)))
    head = draw_head(np.random.default_rng(seed + 1000), 4, noise_mm=0.004)
    run = draw_calibration(np.random.default_rng(seed), head.true, props, 100, noise_mm=0.004, temp_span_c=(18.0, 22.0))
    write_export(run.export, tmp / "cal.csv")
    (tmp / "plane.json").write_text(json.dumps({"normal": [float(v) for v in run.plane[0]],
                                                "offset": float(run.plane[1])}))
    lay = head.nominal
    terms = HeadTerms((Scale((1,), [0.0], np.array([0.005]), lay.names),
                       Drift((2,), [0.0], np.array([0.005]), lay.names, variable="temp", ref=20.0)),
                      np.diag([0.005 ** 2] * 2), np.zeros((20, 2)))
    base = np.diag(np.tile([2.0 ** 2] * 3 + [0.1 ** 2] * 2, 4))
    save_layout(replace(lay, effects=terms, covariance=base), tmp / "extended.toml")
    return load_dataset(tmp / "cal.csv", tmp / "plane.json", tmp / "extended.toml")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[5, 6, 7, 8, 9, 10])
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("benchmarks/results/study_terms_filter.md"))
    a = ap.parse_args(argv)
    from metrology.calibration.calibrate import calibrate_dataset

    load0 = os.getloadavg()[0]
    rows, times = [], {m: [] for m in METHODS}
    for seed in a.seeds:
        ds = dataset(pathlib.Path(tempfile.mkdtemp()), seed)
        got = {}
        for m in METHODS:
            t0 = time.perf_counter()
            rep = calibrate_dataset(ds, m)
            times[m].append(time.perf_counter() - t0)
            got[m] = {t["label"]: next(iter(t["params"].values())) for t in rep.terms.to_dict()}
        for label, truth in (("scale.L2", GAIN), ("drift.L3@temp", RATE)):
            ref = got["lsq"][label]
            cells = []
            for m in METHODS:
                v, se = got[m][label]["value"], got[m][label]["stderr"]
                cells.append(f"{v:+.5f} ± {se:.5f} ({(v - truth) / se:+.2f}σ; {(v - ref['value']) / max(se, ref['stderr']):+.2f}σ)")
            rows.append(f"| {seed} | {label} | " + " | ".join(cells) + " |")
    head = ["| seed | term | " + " | ".join(f"{m}: value ± σ (from truth; from lsq)" for m in METHODS) + " |",
            "|---" * (2 + len(METHODS)) + "|"]
    t = ", ".join(f"{m} {np.median(times[m]):.2f} s" for m in METHODS)
    text = "\n".join([f"# {__doc__.splitlines()[0]}", "", f"Command: `python benchmarks/study_terms_filter.py --seeds "
                      f"{' '.join(map(str, a.seeds))}`; load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} "
                      f"at the end (2 cores, shared). Truth: scale.L2 k = {GAIN}, drift.L3 = {RATE} mm/K.", "",
                      *head, *rows, "", f"Median time per calibration (calibrate_dataset): {t}.", ""])
    a.out.write_text(text)
    sys.stdout.write(text)


if __name__ == "__main__":
    main()

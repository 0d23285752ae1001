"""How should a hole's micro-plane weigh its readings? (issue 49: one estimator for both fitters)

The spots' heights along the normal are independent (block-diagonal calibration) with variances

    v_i = sigma_i^2 (m . u_i)^2 + r_i^T C_ii r_i        (reading noise along the beam; sensor i's calibration)

(``m = (-g_x, -g_y, 1)``, ``r_i = (m, d_i m.e1_i, d_i m.e2_i)``, :mod:`metrology.measure.terms`). Gauss-Markov
weighs each by ``1 / v_i``. Compared on the same holes (paired): the micro-plane unweighted (metro before
issue 49), weighted
by the noise alone (``v_i = sigma_i^2 (m . u_i)^2``) and by noise and calibration, each with ``v_i`` taken at the head
square to the panel (``m = e_z``: fixed, one solve) or at the unweighted fit's normal (two solves).

Heads: the paper's Table 2 (turned to beams +z, as benchmarks/study_measure.py) and Table 6, random 4-sensor
rings (metrology.sim.forward.draw_head: inclinations 15-35 deg, skew), a random 3-sensor ring (control: three
points fix the plane, every weighting gives the same). Per calibration: the head's true layout perturbed from
the nominal (forward.perturb_layout), calibrated by metro's least squares from ``--poses`` poses the forward
simulator draws (study_measure.calibrate_head), holes on a flat panel at true angles uniform 0.5-5 deg
(forward.log.simulate_cell), measured with the calibrated layout and its covariance. Per head and weighting:
the median and RMS error of the angle, and the coverage of the true angle by angle +- U95 (the budget's
reading noise and calibration, :func:`metrology.measure.budget.combine`), over calibrations x holes.

    nice -n 10 python benchmarks/study_weights.py --calibrations 30 --holes 400 --seed 49 [--noisy 3]
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

WEIGHTINGS = ("unweighted", "noise at e_z", "noise at the fit", "noise + calibration at e_z",
              "noise + calibration at the fit")


def _fit(layout, d, v):
    """Weighted micro-plane of readings ``d (N, n)``, weights ``1 / v`` ((n, N) or None: equal): ``g (N, 2)`` and
    the tilt's change per unit height ``A0, A1 (n, N)``."""
    E, u = layout.zero, layout.direction
    dT = d.T
    x, y, z = (E[:, k, None] + dT * u[:, k, None] for k in range(3))
    w = np.ones_like(x) if v is None else 1.0 / v
    sw = w.sum(0)
    xc, yc, zc = (a - (w * a).sum(0) / sw for a in (x, y, z))
    sxx, syy, sxy = (w * xc * xc).sum(0), (w * yc * yc).sum(0), (w * xc * yc).sum(0)
    sxz, syz = (w * xc * zc).sum(0), (w * yc * zc).sum(0)
    det = sxx * syy - sxy * sxy
    gx, gy = (syy * sxz - sxy * syz) / det, (sxx * syz - sxy * sxz) / det
    return np.stack([gx, gy], 1), w * (syy * xc - sxy * yc) / det, w * (sxx * yc - sxy * xc) / det


def _variance(layout, cov, dT, g, sigma):
    from metrology.measure.terms import calibration_source

    gx, gy = g[:, 0], g[:, 1]
    u = layout.direction
    mu = u[:, 2, None] - gx * u[:, 0, None] - gy * u[:, 1, None]
    one = np.ones_like(dT)
    _, q = calibration_source(layout, cov, dT, (-gx * one, -gy * one, one), one, one)
    return (mu * sigma[:, None]) ** 2 + q, mu


def measure(layout, d, weighting):
    """angle, U95 (N,) rad of holes ``d`` with ``weighting`` (one of :data:`WEIGHTINGS`)."""
    from metrology.measure.budget import Budget, combine
    from metrology.measure.terms import calibration_source, noise_source, reading_sigma

    cov, sigma = layout.covariance, reading_sigma(layout)
    dT = np.ascontiguousarray(d.T)
    N = len(d)
    g, A0, A1 = _fit(layout, d, None)
    if weighting.startswith("noise at"):
        _, mu = _variance(layout, cov, dT, g if weighting.endswith("fit") else np.zeros((N, 2)), sigma)
        g, A0, A1 = _fit(layout, d, (mu * sigma[:, None]) ** 2)
    elif weighting.startswith("noise + calibration"):
        g, A0, A1 = _fit(layout, d, _variance(layout, cov, dT, g if weighting.endswith("fit") else np.zeros((N, 2)),
                                              sigma)[0])
    gx, gy = g[:, 0], g[:, 1]
    _, mu = _variance(layout, cov, dT, g, sigma)
    cal, _ = calibration_source(layout, cov, dT, (-gx, -gy, 1.0), A0, A1)
    un = combine(Budget(g, (noise_source(A0, A1, mu, sigma), cal)))
    return un.angle, un.U95


def heads(rng, n_rings):
    from study_measure import heads as paper_heads

    from metrology.core.layout import SensorLayout
    from metrology.sim.forward import draw_head

    h = paper_heads(rng)
    out = {"table2": h["table2"], "table6": h["table6"]}
    for i in range(n_rings):
        r = draw_head(rng, 4).nominal
        out[f"ring4 #{i + 1}"] = SensorLayout(r.names, r.zero, r.direction)
    out["ring3"] = h["ring3"]
    return out


def run(args):
    from study_measure import calibrate_head

    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.panels import make_panel

    rng = np.random.default_rng(args.seed)
    range_mm = np.array([30.0, 70.0])
    rows = []
    print("| head | weighting | median error [deg] | RMS error [deg] | RMS error / unweighted's (same holes; ± s.e. over calibrations) | "
          "coverage % | median U95 [deg] | holes |")
    print("|---|---|---|---|---|---|---|---|")
    for hname, nominal in heads(rng, args.rings).items():
        t0 = time.perf_counter()
        err = {w: [] for w in WEIGHTINGS}
        hit = {w: [] for w in WEIGHTINGS}
        u95 = {w: [] for w in WEIGHTINGS}
        for _ in range(args.calibrations):
            true = perturb_layout(rng, nominal)
            noise = np.full(true.n, args.noise)
            noise[0] *= args.noisy  # one sensor noisier in production (stated in the layout)
            true = true.with_params(true.zero, true.direction, noise_mm=noise, range_mm=np.tile(range_mm, (true.n, 1)))
            cal = calibrate_head(rng, nominal, true, args.noise, range_mm, args.poses)
            cal = cal.with_params(cal.zero, cal.direction, noise_mm=noise)
            spec = LogSpec(true_layout=true, cell_layout=cal, panel=make_panel("flat"), spin_rad=np.pi)
            ch = next(simulate_cell(spec, int(rng.integers(2**31)), 0, args.holes, chunk_holes=args.holes))
            for d, truth in ((ch.d, ch.true_angle), (ch.d_after, ch.true_after)):
                ok = np.all(np.isfinite(d), axis=1)
                for w in WEIGHTINGS:
                    ang, U = measure(cal, d[ok], w)
                    e = np.abs(ang - truth[ok])
                    err[w].append(e)
                    hit[w].append(e <= U)
                    u95[w].append(U)
        base = np.concatenate(err["unweighted"])
        for w in WEIGHTINGS:
            e = np.concatenate(err[w])
            # the ratio per calibration (its holes share it), before and after in turn: its mean's standard error
            per = np.array([np.sqrt(np.mean(a * a) / np.mean(b * b)) for a, b in zip(err[w], err["unweighted"])])
            row = {"head": hname, "weighting": w, "median_err_deg": float(np.degrees(np.median(e))),
                   "rms_err_deg": float(np.degrees(np.sqrt(np.mean(e * e)))),
                   "rms_ratio": float(np.sqrt(np.mean(e * e) / np.mean(base * base))),
                   "ratio_se": float(per.std(ddof=1) / np.sqrt(len(per))),
                   "coverage": float(np.concatenate(hit[w]).mean()),
                   "median_U95_deg": float(np.degrees(np.median(np.concatenate(u95[w])))), "holes": int(e.size),
                   "seconds": round(time.perf_counter() - t0, 1)}
            rows.append(row)
            print(f"| {hname} | {w} | {row['median_err_deg']:.5f} | {row['rms_err_deg']:.5f} | {row['rms_ratio']:.4f} ± {row['ratio_se']:.4f} | "
                  f"{100 * row['coverage']:.1f} | {row['median_U95_deg']:.5f} | {row['holes']} |", flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calibrations", type=int, default=30)
    ap.add_argument("--holes", type=int, default=400, help="holes per calibration (before and after: twice these)")
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--noise", type=float, default=0.005, help="reading noise, mm (1 sigma)")
    ap.add_argument("--noisy", type=float, default=1.0, help="sensor L1's production noise is this many times the rest")
    ap.add_argument("--rings", type=int, default=3, help="random 4-sensor rings")
    ap.add_argument("--seed", type=int, default=49)
    run(ap.parse_args(argv))


if __name__ == "__main__":
    main()

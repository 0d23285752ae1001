"""Can the head's spin be read by pooling the redundant reading's misfit over neighbouring holes (issue 53)?

Without the commanded pose metro reads the spin hole by hole from the redundant reading's misfit
(metrology/measure/spin.py: ``psi = -rho(0) / s``, ``s`` the misfit's slope in the spin). Where a hole's read is too
loose (Table 2 on R 50: ``SPIN_READ_MAX``), a spin that is common to a run, or drifts slowly along it, could be read
from many holes at once: a robust running estimate (the median of the holes' reads over a window). This study
measures, on logs drawn by the forward simulator (the spin per hole, one per log, or a sine along the log:
``study_tight_radii.spin_path``):

- each hole's read against the simulator's spin (the read metro makes, instrumented: ``spin._estimate`` is wrapped
  to keep its inputs; the holes it reads are matched to the log's rows by their readings);
- the pooled read (the running median of the holes' unclipped reads over ``--window`` holes) against the truth,
  and the test a pooled read must pass before it is used: the reads' scatter about it over their own doubts
  (``z = 1.4826 MAD(read - pooled) / median(u_psi)``: ~1 where the spin is common, beyond where it is not);
- the misfit's shape in the spin: its slope and its curvature from fits at ``-spin, 0, +spin``; where the misfit is
  even in the spin (``|c| spin / |s|`` of order 1 and beyond) its sign cannot be read, pooled or not.

    nice -n 10 python benchmarks/study_spin_pool.py --heads table2,table6 --radius 50 --calibrations 3 --holes 120

Results: benchmarks/results/tight_radii.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _one_blas_thread  # noqa: E402,F401


def _instrument():
    """Wrap ``spin._estimate`` to keep, per call, the holes' readings, misfits at ``-spin, 0, +spin`` and the read."""
    import metrology.measure.spin as sp

    calls, orig = [], sp._estimate

    def est(fit, r0, spin):
        out = orig(fit, r0, spin)
        every, zero = np.arange(len(r0)), np.zeros(len(r0))
        dd = next(c.cell_contents for c in fit.__closure__
                  if isinstance(c.cell_contents, np.ndarray) and c.cell_contents.ndim == 2)
        rp, rm = out[3].residual, fit(every, -spin, zero)[0].residual
        with np.errstate(invalid="ignore", divide="ignore"):
            slope = (rp - r0) / spin
            calls.append({"dd": dd.copy(), "raw": -r0 / slope, "u": out[3].residual_sd / np.abs(slope), "used": out[1] < spin,
                          "psi": out[0], "s": (rp - rm) / (2 * spin), "c": (rp + rm - 2 * r0) / (2 * spin ** 2), "spin": spin})
        return out

    sp._estimate = est
    return calls


def running_median(x, w):
    """The median of ``x`` over a centred window of ``w`` holes (NaN left out)."""
    h = w // 2
    return np.array([np.nanmedian(x[max(0, i - h):i + h + 1]) for i in range(len(x))])


def run(args):
    from study_measure import calibrate_head
    from study_tight_radii import all_heads, one_log, spin_path

    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.panels import make_panel

    calls = _instrument()
    heads = all_heads(np.random.default_rng(args.seed))
    print("| head | spin along the log | holes read / in the log | per-hole read: median abs error [deg] | used by metro | "
          "pooled (running median of " f"{args.window}): median abs error [deg] | scatter z (1: common) | misfit's "
          "|curvature| spin / |slope| (median) |")
    print("|" + "---|" * 8)
    for hname in args.heads.split(","):
        for along in args.along.split(","):
            rng = np.random.default_rng([args.seed, 7])
            stats = {k: [] for k in ("e1", "ep", "used", "z", "even", "n", "m")}
            for _ in range(args.calibrations):
                nominal = heads[hname]
                true = perturb_layout(rng, nominal)
                true = true.with_params(true.zero, true.direction, noise_mm=np.full(true.n, 0.005),
                                        range_mm=np.tile([30.0, 70.0], (true.n, 1)))
                cal = calibrate_head(rng, nominal, true, 0.005, np.array([30.0, 70.0]), 60)
                panel = make_panel("cylinder", args.radius, axis=(1.0, 0.0, 0.0) if args.orient == "along" else (0.0, 1.0, 0.0))
                path = spin_path(rng, along, 2.0, args.drift_holes)
                if path is None:  # the spin per hole, drawn here so that it is known
                    v = np.radians(rng.uniform(-2.0, 2.0, 1 << 16))
                    path = lambda hole, v=v: v[np.asarray(hole) % len(v)]  # noqa: E731
                ch, log, surf = one_log(rng, panel, true, cal, args.holes, 2.0, pose=False, path=path)[:3]
                calls.clear()
                measure_batch(cal, log, Settings(surfaces=surf))
                c = calls[0]  # the readings before the adjustment
                d = np.asarray(ch.d)
                idx = np.array([np.flatnonzero((np.abs(d - row) < 1e-9).all(1))[0] for row in c["dd"]])
                order = np.argsort(idx)
                idx = idx[order]
                truth = np.asarray(path(np.asarray(ch.hole)[idx]))
                raw, u = c["raw"][order], c["u"][order]
                sp = c["spin"][order]
                pooled = running_median(np.clip(raw, -2 * sp, 2 * sp), args.window)
                stats["e1"].append(np.abs(np.clip(raw, -sp, sp) - truth))
                stats["ep"].append(np.abs(pooled - truth))
                stats["used"].append(c["used"][order])
                res = raw - pooled
                stats["z"].append(1.4826 * np.nanmedian(np.abs(res - np.nanmedian(res))) / np.nanmedian(u))
                stats["even"].append(np.abs(c["c"][order]) * c["spin"][order] / np.abs(c["s"][order]))
                stats["n"].append(len(idx))
                stats["m"].append(len(d))
            cat = {k: np.concatenate(v) if k in ("e1", "ep", "used", "even") else np.asarray(v) for k, v in stats.items()}
            print(f"| {hname} | {along} | {cat['n'].sum()} / {cat['m'].sum()} | {np.degrees(np.nanmedian(cat['e1'])):.2f} | "
                  f"{100 * cat['used'].mean():.0f} % | {np.degrees(np.nanmedian(cat['ep'])):.2f} | "
                  f"{', '.join(f'{z:.1f}' for z in cat['z'])} | {np.nanmedian(cat['even']):.2f} |", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--heads", default="table2,table6")
    ap.add_argument("--along", default="hole,run,drift")
    ap.add_argument("--radius", type=float, default=50.0)
    ap.add_argument("--orient", default="along")
    ap.add_argument("--calibrations", type=int, default=3)
    ap.add_argument("--holes", type=int, default=120)
    ap.add_argument("--window", type=int, default=31, help="holes in the running median")
    ap.add_argument("--drift-holes", type=float, default=400.0)
    ap.add_argument("--seed", type=int, default=53)
    run(ap.parse_args(argv))


if __name__ == "__main__":
    main()

"""Planned poses against random ones, on the independent forward simulator.

For each head (the paper's Table 2 and Table 6 layouts, and random 3-sensor rings) and seed:
the true layout is the nominal moved by 0.1-1 mm and 0.1-2 deg (``sim.forward.perturb_layout``),
the datum a random flat plate (``draw_surface``) scanned by the tracker (``sample_cloud``, 10 um);
``metro plan`` chooses N poses from the nominal layout, the plane fitted to the scan and the
scan's extent; random poses of the paper's kind under the same limits are the first feasible
candidates. Readings are cast at the plate by ``sim.forward.cast_beams`` from the true layout
(noise ``--noise-mm``; a reading outside the range is no reading) and every pose set is
calibrated by batch least squares on its first k poses. Reported: the median over seeds of the
largest zero-point error (mm) and beam-direction error (deg) against k, the smallest k at which
the plan reaches what 100 random poses reach, and the coverage of the plan's predicted sigma
(fraction of |error| / sigma_predicted <= 1.96 over every parameter and seed; 0.95 expected).

    nice -n 10 python benchmarks/study_plan.py [--seeds 12] [--poses 40] [--noise-mm 0.005] [--candidates 5000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from metrology.calibration.estimators import lsq
from metrology.core.frames import plane_in_tcs
from metrology.core.model import tangent_from_direction
from metrology.core.observations import Observations
from metrology.core.paper import table2_layouts, table6_layouts
from metrology.core.plane import fit_plane_tls
from metrology.plan import (DatumExtent, Limits, covariance, draw_candidates, feasible, plan_poses,
                            pose_information)
from metrology.sim.forward import cast_beams, draw_head, draw_surface, perturb_layout, sample_cloud

KS = (6, 8, 10, 12, 15, 18, 20, 22, 25, 30, 40)
N_RANDOM = 100


def _nominal(kind, rng, noise):
    from dataclasses import replace

    if kind == "ring3":
        return draw_head(rng, 3, noise_mm=noise, range_mm=(30.0, 70.0)).nominal
    lay = (table2_layouts if kind == "table2" else table6_layouts)()[0]
    return replace(lay, noise_mm=np.full(lay.n, noise), range_mm=np.tile([40.0, 60.0], (lay.n, 1)))


def scene(kind, rng, noise, tilt_deg=10.0):
    """Nominal and true layouts, the plate, its scan, the fitted plane, its extent and the limits
    (stand-off: the range less 2 mm; the tool on the plate's side its normal points to)."""
    nominal = _nominal(kind, rng, noise)
    true = perturb_layout(rng, nominal)
    surface, _ = draw_surface(rng)
    cloud = sample_cloud(surface, rng, 2000)
    plane = fit_plane_tls(cloud)[0]
    extent = DatumExtent.from_points(plane, cloud)
    lo, hi = nominal.range_mm[:, 0].max() + 2.0, nominal.range_mm[:, 1].min() - 2.0
    limits = Limits(np.deg2rad(tilt_deg), (lo, hi), nominal.range_mm,
                    tool_side=1.0 if plane.normal @ surface.normal > 0 else -1.0)
    return nominal, true, surface, cloud, plane, extent, limits


def _errors(nominal, true, rot, trans, d, plane, k):
    """Largest zero error (mm), largest beam error (deg) and chart error (n, 5) of lsq on the first k poses."""
    N, D = plane_in_tcs(plane.normal, plane.offset, rot[:k], trans[:k])
    try:
        cal = lsq(nominal, Observations(N, D, d[:k]))
    except ValueError:
        return np.inf, np.inf, None
    dz = np.linalg.norm(cal.layout.zero - true.zero, axis=1).max()
    cos = np.clip(np.sum(cal.layout.direction * true.direction, axis=1), -1, 1)
    return dz, np.degrees(np.arccos(cos)).max(), cal.theta


def trial(kind, seed, n_poses, noise, n_candidates=5000):
    rng = np.random.default_rng([seed, ("table2", "table6", "ring3").index(kind)])
    nominal, true, surface, cloud, plane, extent, limits = scene(kind, rng, noise)
    plan = plan_poses(nominal, plane, extent, n_poses, limits, nominal.noise_mm, rng, n_candidates=n_candidates,
                      robustness_trials=0)
    cands = draw_candidates(rng, nominal, plane, extent, 3000, limits)
    rand = cands.select(np.flatnonzero(feasible(nominal, plane, extent, cands, limits))[:N_RANDOM])
    theta_true = np.concatenate([true.zero - nominal.zero, tangent_from_direction(nominal.direction, true.direction)], 1)
    out = {}
    for label, poses in (("planned", plan.planned.poses), ("random", rand)):
        hits = cast_beams(surface, true.zero, true.direction, poses.rot, poses.trans)
        d = hits.d + rng.normal(scale=noise, size=hits.d.shape)
        d = np.where((d >= nominal.range_mm[:, 0]) & (d <= nominal.range_mm[:, 1]), d, np.nan)
        ks = [k for k in (*KS, N_RANDOM) if k <= len(poses)]
        res = {k: _errors(nominal, true, poses.rot, poses.trans, d, plane, k) for k in ks}
        out[label] = {k: r[:2] for k, r in res.items()}
        # coverage of the predicted sigma (nominal linearisation, before any data) at k = 20 and 100
        for k in (20, N_RANDOM):
            if k in res and res[k][2] is not None:
                X = pose_information(nominal, *poses.select(np.arange(k)).plane_in_tcs(plane), nominal.noise_mm)
                se = np.sqrt(np.einsum("nii->ni", covariance(X)))
                out[f"{label}_z{k}"] = ((res[k][2] - theta_true) / se).ravel()
    return out


def follow_demo(seed, n_poses, noise, target_mm=0.1, target_deg=0.1):
    """A planned table6 file filled by the forward simulator, fed pose by pose to ``--follow``:
    where it stops, and its result against batch least squares on the same poses."""
    import json
    import math
    import tempfile
    from pathlib import Path

    from metrology.calibration.follow import Targets
    from metrology.core.frames import quaternion_from_matrix
    from metrology.io.export import TrackerExport, write_export
    from metrology.io.layout import save_layout
    from metrology.jobs.calibrate import calibrate_files
    from metrology.jobs.follow import follow_export

    rng = np.random.default_rng([seed, 1])
    nominal, true, surface, _, plane, extent, limits = scene("table6", rng, noise)
    poses = plan_poses(nominal, plane, extent, n_poses, limits, nominal.noise_mm, rng, robustness_trials=0).planned.poses
    hits = cast_beams(surface, true.zero, true.direction, poses.rot, poses.trans)
    d = hits.d + rng.normal(scale=noise, size=hits.d.shape)
    ids = tuple(f"P{k + 1:03d}" for k in range(len(poses)))
    nan = np.full(len(poses), np.nan)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_export(TrackerExport(ids, nan, nan, quaternion_from_matrix(poses.rot), poses.trans, nominal.names, d),
                     tmp / "e.csv")
        (tmp / "p.json").write_text(json.dumps({"normal": plane.normal.tolist(), "offset": plane.offset}))
        save_layout(nominal, tmp / "l.toml")
        res = follow_export(str(tmp / "e.csv"), tmp / "p.json", tmp / "l.toml",
                            Targets(target_mm, math.radians(target_deg)), idle_s=0, stop_when_met=True)
        k = len(res.steps)
        lines = (tmp / "e.csv").read_text().splitlines()
        (tmp / "k.csv").write_text("\n".join(lines[: k + 1]) + "\n")
        batch = calibrate_files(tmp / "k.csv", tmp / "p.json", tmp / "l.toml", "lsq").calibration
    diff = np.abs(res.report.calibration.theta - batch.theta) / batch.stderr
    err = np.linalg.norm(res.report.calibration.layout.zero - true.zero, axis=1).max()
    print(f"\nfollow on a planned table6 file (seed {seed}, targets {target_mm} mm, {target_deg} deg): stopped "
          f"({res.stopped}) at pose {res.steps[-1].pose_id} of {len(poses)}; largest zero error {err:.3f} mm; "
          f"|follow - batch lsq| <= {diff.max():.3f} sigma")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--poses", type=int, default=40)
    ap.add_argument("--noise-mm", type=float, default=0.005)
    ap.add_argument("--kinds", default="table2,table6,ring3")
    ap.add_argument("--candidates", type=int, default=5000, help="candidate poses the plan chooses from")
    args = ap.parse_args()
    print(f"{args.seeds} seeds per head, noise {args.noise_mm} mm, tilt <= 10 deg, planned N = {args.poses}, "
          f"random {N_RANDOM}, {args.candidates} candidates; medians over seeds of the largest zero error (mm) / beam error (deg), lsq")
    t0 = time.process_time()
    summary = []
    for kind in args.kinds.split(","):
        trials = [trial(kind, s, args.poses, args.noise_mm, args.candidates) for s in range(args.seeds)]
        med = lambda lab, k, j: float(np.median([t[lab][k][j] for t in trials if k in t[lab]]))  # noqa: E731
        print(f"\n{kind}: k | planned zero mm, beam deg | random zero mm, beam deg")
        for k in (*KS, N_RANDOM):
            p = f"{med('planned', k, 0):8.4f} {med('planned', k, 1):8.4f}" if k <= args.poses else " " * 17
            print(f"  {k:4d} | {p} | {med('random', k, 0):8.4f} {med('random', k, 1):8.4f}")
        ref = (med("random", N_RANDOM, 0), med("random", N_RANDOM, 1))
        ks = [k for k in KS if k <= args.poses]
        ok = [med("planned", k, 0) <= ref[0] and med("planned", k, 1) <= ref[1] for k in ks]
        reach = [k for j, k in enumerate(ks) if all(ok[j:])]  # from k on, every larger k meets it too
        cov = {}
        for key in ("planned_z20", "random_z20", "random_z100"):
            z = np.concatenate([t[key] for t in trials if key in t])
            z = z[np.isfinite(z)]
            cov[key] = (float(np.mean(np.abs(z) <= 1.96)), float(np.sqrt(np.mean(z**2))), len(z))
        summary.append((kind, ref, reach[0] if reach else None, med("planned", 20, 0), med("planned", 20, 1), cov))
        print(f"  planned poses to reach random-{N_RANDOM}: {reach[0] if reach else 'not within ' + str(args.poses)}")
        for key, (c, r, m) in cov.items():
            print(f"  coverage {key}: {c:.3f} within 1.96 sigma, RMS z {r:.2f} ({m} values)")
    print("\n| head | random 100: zero mm, beam deg | planned 20: zero mm, beam deg | planned poses to reach random 100 "
          "| coverage planned 20 (95 % expected) | RMS z planned 20 |")
    print("|---|---|---|---|---|---|")
    for kind, ref, reach, pz, pb, cov in summary:
        c, r, _ = cov["planned_z20"]
        print(f"| {kind} | {ref[0]:.3f}, {ref[1]:.3f} | {pz:.3f}, {pb:.3f} | {reach} | {100 * c:.1f} % | {r:.2f} |")
    follow_demo(0, args.poses, args.noise_mm)
    print(f"\nCPU {time.process_time() - t0:.0f} s")


if __name__ == "__main__":
    main()

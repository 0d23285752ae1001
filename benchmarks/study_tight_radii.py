"""Tight radii (issue 53): does `angle ± U95` of `metro measure --panel --points` hold on leading edges,
lips and tubes, and is a hole the local model cannot represent `not_measured` with its reason?

Everything drawn by the independent forward simulator (metrology/sim/forward), as
benchmarks/study_measure.py ``--panel-known`` does it:

1. each head's true layout (forward.head.perturb_layout of the nominal) and its calibration by metro
   (``study_measure.calibrate_head``: poses over a flat datum, lsq, the layout with its covariance);
2. a cylinder of radius R (20, 50, 80, 150 mm, and a flat panel for the reference) with its axis along
   the panel's ``x`` or across it (along ``y``); the holes on its crest (a hole table along the axis,
   feed ``-z``), drilled by the simulator from the table (the log carries the commanded pose:
   ``pose_*`` columns; ``--no-pose`` drops them); a torus lip (``--lips``: tube radii, ``--lip-ring`` the ring's
   radius; :class:`metrology.sim.forward.torus.TorusPanel`, its outer side elliptic, its inner a saddle), the holes
   around its crest, each feed on the lip's normal;
3. the CAD a grid mesh of the simulator's own surface (``--mesh-step`` mm, tests/measure/panel_fixtures.py;
   a binary STL is the same triangles), the hole table the drill points;
4. measured by ``metrology.measure.holes.measure_batch`` with the surfaces of
   ``metrology.jobs.measure_panel.panel_hole_surfaces`` (what ``metro measure --panel --points`` runs).

Per row: the share of holes judged (status not ``not_measured``), U95 coverage of the true
angle among them (before and after the adjustment), the median error of the measured angle over the flat
panel's (same head), the share of holes whose readings rule 2 calls "disagree" (more than half of them refuses
the log: ``jobs.measure._check_fit``), and the reasons of the holes not measured.

    nice -n 10 python benchmarks/study_tight_radii.py --calibrations 4 --holes 150 --seed 53 \
        --json benchmarks/results/tight_radii_seed53.json [--heads table6,ring3] [--radii 20,50] [--lips 50,80]
        [--no-pose [--sim-spin-deg 0]]

Without the pose each row also measures the same logs with their pose (the last two columns).

Results and what they found: benchmarks/results/tight_radii.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _one_blas_thread  # noqa: E402,F401


def all_heads(rng):
    """The study's heads: Table 2 and Table 6 (4 sensors), a drawn 3-sensor ring and a drawn 4-sensor ring."""
    from study_measure import heads

    from metrology.core.layout import SensorLayout
    from metrology.sim.forward import draw_head

    h = heads(rng)
    four = draw_head(rng, 4).nominal
    h["ring4"] = SensorLayout(four.names, four.zero, four.direction)
    return h


def crest_table(panel, span_mm: float, m: int, name="holes"):
    """The forward simulator's hole table of ``m`` holes on the crest of ``panel`` (along its axis, or along
    ``x`` on a flat panel, ``|t| <= span_mm``), feed ``-n`` (the panel's normal there)."""
    from metrology.sim.forward.holes import HoleTable

    axis = np.asarray(getattr(panel, "axis", (1.0, 0.0, 0.0)), float)
    t = np.linspace(-span_mm, span_mm, m)
    P = t[:, None] * axis[None, :]
    P[:, 2] = panel.height(P[:, 0], P[:, 1])
    feed = -panel.normal_at(P)
    return HoleTable(name, tuple(f"H{i:04d}" for i in range(m)), P, feed)


def spin_path(rng, along: str, spin_deg: float, drift_holes: float):
    """The head's spin along the log (``LogSpec.spin_path``): ``hole`` None (uniform per hole, as the simulator
    draws it); ``run`` one spin for the whole log, uniform within +-spin; ``drift`` a sine of amplitude spin and
    period ``drift_holes`` holes, its phase drawn; ``bound`` one spin for the whole log at a bound (+-spin, its sign
    drawn: a cell held at the edge of its convention)."""
    spin = np.radians(spin_deg)
    if along == "bound":
        v = float(spin * rng.choice((-1.0, 1.0)))
        return lambda hole: np.full(len(hole), v)
    if along == "run":
        v = float(rng.uniform(-spin, spin))
        return lambda hole: np.full(len(hole), v)
    if along == "drift":
        phase = float(rng.uniform(0.0, 2 * np.pi))
        return lambda hole: spin * np.sin(2 * np.pi * np.asarray(hole) / drift_holes + phase)
    return None


def centre_pose(spec, ch):
    """The log's commanded pose with the head's spin at the convention's centre (0): what an estimator that knows
    only that the spin lies within +-spin takes (the floor without a redundant reading)."""
    from dataclasses import replace

    from metrology.sim.forward.log import _head, rotation_vector
    from metrology.sim.forward.log_write import log_table

    s = spec.axis_sign
    feed = spec.table.feed[np.asarray(ch.hole) % spec.table.m]
    return log_table(replace(ch, pose_rotvec=rotation_vector(_head(feed, np.array([1.0, -s, -s]), np.zeros(len(feed))))))


def step_cad(panel, folder):
    """The simulator's cylinder (axis through ``(0, 0, -R)`` along ``x`` or ``y``, 400 mm long) written as a STEP
    B-rep by OpenCASCADE and loaded as ``metro measure --panel`` loads a STEP (``--cad step``: the B-rep path)."""
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeCylinder
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    from metrology.panel.mesh import load_panel

    R, a = panel.radius_mm, np.asarray(panel.axis, float)
    start = -200.0 * a + np.array([0.0, 0.0, -R])
    shape = BRepPrimAPI_MakeCylinder(gp_Ax2(gp_Pnt(*start), gp_Dir(*a)), R, 400.0).Shape()
    w = STEPControl_Writer()
    w.Transfer(shape, STEPControl_AsIs)
    path = Path(folder) / f"cylinder_R{R:g}_{'x' if a[0] else 'y'}.step"
    if w.Write(str(path)) != IFSelect_RetDone:
        raise RuntimeError(f"OpenCASCADE could not write {path}")
    return load_panel(path)


def one_log(rng, panel, true, cal, holes, mesh_step, pose=True, same=False, spin_deg=2.0, path=None, cad=None):
    """``(chunk, log table, HoleSurfaces)``: ``holes`` holes on ``panel``'s crest measured with a grid mesh; without
    the pose and ``same``, also the log with its pose, its surfaces, and the log with its pose at the spin's centre
    (:func:`centre_pose`); ``path`` the spin along the log (:func:`spin_path`)."""
    from dataclasses import replace

    from metrology.jobs.measure_panel import footprint_mm, panel_hole_surfaces
    from metrology.measure.panel import HoleTable
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.log_write import log_table
    from tests.measure.panel_fixtures import panel_mesh

    table = crest_table(panel, 100.0, holes)
    spec = LogSpec(true_layout=true, cell_layout=cal, panel=panel, table=table, spin_rad=np.radians(spin_deg),
                   spin_path=path)
    ch = next(simulate_cell(spec, int(rng.integers(2**31)), 0, holes, chunk_holes=holes))
    log = log_table(ch)
    if not pose:
        log = log.drop_columns([c for c in log.column_names if c.startswith("pose_")])
    cad = cad or Panel(panel_mesh(panel, half_mm=160.0, step_mm=mesh_step))
    surf = panel_hole_surfaces(cad, HoleTable(table.ids, table.points, table.feed, "holes"), footprint_mm(cal),
                               0.5, 0.0, 0.0 if pose else np.radians(2.0))
    if not pose and same:  # the same log with its pose, measured as such (the spin's cost, on the same draws)
        return ch, log, surf, log_table(ch), replace(surf, spin=0.0), centre_pose(spec, ch)
    return ch, log, surf


def _reason_key(r: str) -> str:
    """A reason without its numbers (for the histogram)."""
    import re

    return re.sub(r"[-+]?\d[\d.,]*(e[-+]?\d+)?", "#", r)[:120]


def run(args):
    from metrology.measure import spin as spin_rules
    from metrology.measure.batch import CODE, Status
    from metrology.measure.budget import Kind

    if args.spin_model:  # a candidate rule, measured against metro's own (benchmarks/results/tight_radii.md)
        spin_rules.SPIN_BOUND_MODEL = Kind(args.spin_model)
    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.panels import make_panel
    from metrology.sim.forward.torus import TorusPanel

    out = {"args": {k: str(v) for k, v in vars(args).items()}, "rows": []}
    range_mm = np.array([30.0, 70.0])
    heads = all_heads(np.random.default_rng(args.seed))
    radii = [float(r) for r in args.radii.split(",") if r]
    lips = [float(r) for r in args.lips.split(",") if r]
    flat_err = {}
    folder = tempfile.mkdtemp(prefix="tight_radii_step_")
    print(HEADER + (" same logs with the pose: coverage % | median error [deg] | with the pose at the spin's centre: "
                    "median error [deg] |" if args.no_pose else ""))
    print("|" + "---|" * (14 if args.no_pose else 11))
    for hi, (hname, nominal) in enumerate(heads.items()):
        if hname not in args.heads.split(","):
            continue
        cases = [("flat", None, None)] + [(f"cylinder R {R:g} {o}", R, o) for R in radii for o in args.orient.split(",")]
        cases += [(f"torus lip r {r:g} {side}", r, side) for r in lips for side in args.lip_sides.split(",")]
        for pi, (label, R, orient) in enumerate(cases):
            t0 = time.perf_counter()
            rng = np.random.default_rng([args.seed, hi, pi])
            acc = {k: [] for k in ("hit_b", "hit_a", "err", "judged", "u_b", "hit_p", "err_p", "err_c", "u_p", "true_b",
                                   "ang_b", "bound")}
            disagree, refused, reasons, n_all = 0, 0, Counter(), 0
            for c in range(args.calibrations):
                true = perturb_layout(rng, nominal)
                true = true.with_params(true.zero, true.direction, noise_mm=np.full(true.n, args.noise),
                                        range_mm=np.tile(range_mm, (true.n, 1)))
                from study_measure import calibrate_head

                cal = calibrate_head(rng, nominal, true, args.noise, range_mm, args.poses)
                if R is None:
                    panel = make_panel("flat")
                elif label.startswith("torus"):
                    panel = TorusPanel(R, args.lip_ring, orient)
                else:
                    panel = make_panel("cylinder", R, axis=(1.0, 0.0, 0.0) if orient == "along" else (0.0, 1.0, 0.0))
                if args.cad == "step" and c == 0:
                    cad = step_cad(panel, folder) if R is not None and not label.startswith("torus") else None
                path = spin_path(rng, args.spin_along, args.sim_spin_deg, args.drift_holes)
                got = one_log(rng, panel, true, cal, args.holes, args.mesh_step, pose=not args.no_pose, same=args.no_pose,
                              spin_deg=args.sim_spin_deg, path=path, cad=cad if args.cad == "step" else None)
                ch, log, surf = got[:3]
                b = measure_batch(cal, log, Settings(surfaces=surf))
                if args.no_pose:  # the same log with its pose
                    bp = measure_batch(cal, got[3], Settings(surfaces=got[4]))
                    up = np.radians(bp.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
                    okp = (bp.status != CODE[Status.NOT_MEASURED]) & np.isfinite(bp.angle_before) & np.isfinite(up)
                    ep = np.abs(bp.angle_before - ch.true_angle)
                    acc["hit_p"].append(ep[okp] <= up[okp])
                    acc["err_p"].append(ep[okp])
                    bc = measure_batch(cal, got[5], Settings(surfaces=got[4]))  # the pose at the spin's centre: the floor
                    acc["err_c"].append(np.abs(bc.angle_before - ch.true_angle)[np.isfinite(bc.angle_before)])
                t = b.columns
                ub = np.radians(t.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
                ua = np.radians(t.column("U95_after_deg").to_numpy(zero_copy_only=False).astype(float))
                judged = b.status != CODE[Status.NOT_MEASURED]
                okb = judged & np.isfinite(b.angle_before) & np.isfinite(ub)
                oka = judged & np.isfinite(b.angle_after) & np.isfinite(ua)
                acc["hit_b"].append(np.abs(b.angle_before - ch.true_angle)[okb] <= ub[okb])
                acc["hit_a"].append(np.abs(b.angle_after - ch.true_after)[oka] <= ua[oka])
                acc["err"].append(np.abs(b.angle_before - ch.true_angle)[okb])
                acc["u_b"].append(ub[okb])
                acc["true_b"].append(ch.true_angle[okb])
                acc["ang_b"].append(b.angle_before[okb])
                acc["bound"].append(b.spin_bound[okb] if b.spin_bound is not None else np.zeros(int(okb.sum()), bool))
                if args.no_pose:  # U95 on the same logs with the pose (nan where it judged none)
                    acc["u_p"].append(np.where(okp, up, np.nan)[okb])
                acc["judged"].append(judged)
                n_all += len(judged)
                dis = int(b.disagree.sum())
                disagree += dis
                refused += int(len(okb) >= 20 and dis > 0.5 * len(okb))
                status = t.column("status").to_pylist()
                for s, r in zip(status, t.column("reason").to_pylist()):
                    if s == "not_measured":
                        reasons[_reason_key(r or "")] += 1
            if not acc["judged"]:
                continue
            cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in acc.items()}
            med = float(np.degrees(np.median(cat["err"]))) if cat["err"].size else float("nan")
            if R is None:
                flat_err[hname] = med
            row = {"head": hname, "panel": label, "radius_mm": R, "orient": orient, "pose": not args.no_pose,
                   "holes": n_all, "judged": int(cat["judged"].sum()), "share_judged": float(cat["judged"].mean()),
                   "coverage_before": float(cat["hit_b"].mean()) if cat["hit_b"].size else float("nan"),
                   "coverage_after": float(cat["hit_a"].mean()) if cat["hit_a"].size else float("nan"),
                   "holes_after": int(cat["hit_a"].size),
                   "median_err_deg": med, "err_over_flat": med / flat_err.get(hname, np.nan),
                   "median_U95_deg": float(np.degrees(np.median(cat["u_b"]))) if cat["u_b"].size else float("nan"),
                   "disagree": disagree, "logs_refused": refused, "logs": args.calibrations,
                   "not_measured_reasons": dict(reasons.most_common(6)), "seconds": round(time.perf_counter() - t0, 1),
                   "spin_model": args.spin_model or "metro's", "spin_along": args.spin_along,
                   "holes_on_bound": int(cat["bound"].sum()),
                   "coverage_on_bound": float(cat["hit_b"][cat["bound"].astype(bool)].mean()) if cat["bound"].any() else None}
            if args.no_pose and cat["hit_p"].size:  # the same logs with their pose
                row["coverage_pose_same"] = float(cat["hit_p"].mean())
                row["median_err_pose_same_deg"] = float(np.degrees(np.median(cat["err_p"])))
                row["median_err_centre_deg"] = float(np.degrees(np.median(cat["err_c"])))
                row["choices"] = choices(cat, np.radians(args.tol_deg))
            out["rows"].append(row)
            print(line(row), flush=True)
    return out


#: the spin's share of U95^2 (``1 - (U95 with the pose / U95)^2`` on the same log) beyond which choice "B<share>" leaves
#: a hole `not_measured`; choice "B" is metro's own count (``HoleBatch.spin_bound``, measure.spin.SPIN_BOUND_SHARE)
SPIN_SHARES = (0.75,)


def verdicts(angle, U, tol):
    """(conforms, fails) bool arrays, ISO 14253-1 (rule 4): conforms where angle + U95 <= tol, fails where
    angle - U95 > tol (the rest undecided)."""
    return angle + U <= tol, angle - U > tol


def choices(cat, tol):
    """Judge every hole with its U95 (A) or leave `not_measured` those whose U95 rests on the spin's bound (B: metro's
    ``spin_bound``; B<share>: the spin's share of U95^2 beyond :data:`SPIN_SHARES`): per
    choice the share judged, U95 coverage, median error (deg), decisive verdicts, and wrong ones at ``tol`` (rad:
    FAIL on a hole truly within tolerance, CONFORMS on one truly out)."""
    err, U, true, ang = np.abs(cat["ang_b"] - cat["true_b"]), cat["u_b"], cat["true_b"], cat["ang_b"]
    with np.errstate(invalid="ignore"):
        share = np.nan_to_num(1.0 - (cat["u_p"] / U) ** 2, nan=0.0)
    out = {}
    for name, keep in [("A", np.ones(len(U), bool)), ("B", ~cat["bound"])] + [(f"B{x:g}", share <= x) for x in SPIN_SHARES]:
        ok, fail = verdicts(ang[keep], U[keep], tol)
        out[name] = {"judged": float(keep.mean()), "coverage": float((err[keep] <= U[keep]).mean()) if keep.any() else None,
                     "median_err_deg": float(np.degrees(np.median(err[keep]))) if keep.any() else None,
                     "decisive": int(ok.sum() + fail.sum()), "false_fail": int((fail & (true[keep] <= tol)).sum()),
                     "false_conform": int((ok & (true[keep] > tol)).sum()),
                     "truly_within": int((true[keep] <= tol).sum())}
    out["spin_share_median"] = float(np.median(share))
    return out


HEADER = ("| head | panel | judged | coverage before % | after % | median error [deg] | ÷ flat | median U95 [deg] | "
          "disagree | logs refused | s |")


def line(r):
    return (f"| {r['head']} | {r['panel']} | {r['judged']} / {r['holes']} ({100 * r['share_judged']:.0f} %) | "
            f"{100 * r['coverage_before']:.1f} | {100 * r['coverage_after']:.1f} | {r['median_err_deg']:.4f} | "
            f"{r['err_over_flat']:.2f} | {r['median_U95_deg']:.4f} | {r['disagree']} | {r['logs_refused']} / {r['logs']} | "
            f"{r['seconds']:.0f} |" + (f" {100 * r['coverage_pose_same']:.1f} | {r['median_err_pose_same_deg']:.4f} | "
                                       f"{r['median_err_centre_deg']:.4f} |" if "coverage_pose_same" in r else ""))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calibrations", type=int, default=4)
    ap.add_argument("--holes", type=int, default=150, help="holes per calibration (on the crest)")
    ap.add_argument("--poses", type=int, default=60, help="calibration poses")
    ap.add_argument("--noise", type=float, default=0.005, help="reading noise, mm (1 sigma)")
    ap.add_argument("--radii", default="20,50,80,150")
    ap.add_argument("--orient", default="along,across", help="the cylinder's axis along the panel's x, across it")
    ap.add_argument("--lips", default="50,80", help="torus lips' tube radii, mm ('' none)")
    ap.add_argument("--lip-ring", type=float, default=600.0, help="the torus lip's ring radius, mm")
    ap.add_argument("--lip-sides", default="outer,inner", help="the lip's outer side (elliptic), inner (a saddle)")
    ap.add_argument("--heads", default="table2,table6,ring3,ring4")
    ap.add_argument("--mesh-step", type=float, default=2.0, help="the CAD grid mesh's step, mm")
    ap.add_argument("--no-pose", action="store_true", help="the log without the commanded pose")
    ap.add_argument("--sim-spin-deg", type=float, default=2.0,
                    help="the head's true spin about the tool axis, uniform within +-this (measured as +-2 without the pose)")
    ap.add_argument("--spin-along", choices=("hole", "run", "drift", "bound"), default="hole",
                    help="the true spin: drawn per hole (the simulator's default), one per log, drifting along it, or "
                         "one per log at a bound")
    ap.add_argument("--cad", choices=("mesh", "step"), default="mesh",
                    help="the CAD: a grid mesh of the simulator's surface, or its STEP B-rep (cylinders; OpenCASCADE)")
    ap.add_argument("--spin-model", choices=("uniform", "arcsine", "edge"), default=None,
                    help="what U95 takes of a spin known only by its bound (a candidate: overrides "
                         "metrology.measure.spin.SPIN_BOUND_MODEL for this run; default metro's own)")
    ap.add_argument("--drift-holes", type=float, default=400.0, help="--spin-along drift: its period, holes")
    ap.add_argument("--tol-deg", type=float, default=1.0,
                    help="the tolerance the choices' verdicts are counted at (on the angle before; true angles 0.5-5 deg)")
    ap.add_argument("--seed", type=int, default=53)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    out = run(args)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()

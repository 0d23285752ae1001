"""Does `angle ± U95` of `metro measure` hold the true angle in 95 % of holes?

Over many calibrations x holes, for the paper's Table 2 and Table 6 heads and a random 3-sensor ring,
on flat, spherical and cylindrical panels, everything drawn by the independent forward simulator
(metrology/sim/forward, never the fit's own formulas):

1. the head's true layout: the nominal with each zero point moved 0.1-1 mm and each beam turned
   0.1-2 deg (forward.head.perturb_layout);
2. a calibration: `--poses` poses over a flat datum (forward.poses.draw_poses, beams cast by
   forward.beams), readings with Gaussian noise, calibrated by `metrology.calibration` (lsq) to a
   layout carrying its covariance, the datum plane known exactly (its own uncertainty is not
   propagated: see docs/measure.md);
3. a shift of holes on a panel (forward.log: true angle uniform 0.5-5 deg, the cell's adjustment with
   the calibrated layout, after-readings), measured by metrology.measure with that layout;
4. coverage: the share of holes whose true angle lies within angle ± U95, before and after the
   adjustment. On curved panels, with --min-radius-mm R (the curvature bound in U95) and without it
   (what the micro-plane's curvature bias does to a U95 that ignores it).

    python benchmarks/study_measure.py --calibrations 40 --holes 500 --seed 1 --json out.json
        [--scan exact|hand|hand-exact] [--panels flat,sphere,cylinder]

With ``--panel-known`` (``metro measure --panel --points``; issue 36 item 4, one study): the three
heads on the panels of :data:`KNOWN_PANELS`: flat, sphere R 500, cylinders R 500 and R 1000 (each
calibration's holes in ``--axis-groups`` groups, each group's axis at its own random azimuth: the
barrel at any angle to the head), their CAD a 4 mm grid mesh of the simulator's own surface
(tests/measure/panel_fixtures.py), the hole table their drill points, the head's spin within +-2 deg of
the cell's convention; and the generated panels (metrology.sim.forward.shapes: saddle, the wing skin,
the concave barrel, the nacelle lip) drilled from their bundled hole tables (cycled) and measured with
their bundled CAD (metrology/data/panels): the wing once as its mesh (wing.stl) and once as its STEP
B-rep (wing.step, fixtures/make_wing_step.py; needs the step-exact extra), the log as ``metro
simulate-log`` writes it (``point_id``, the commanded pose). Per row: coverage of the true angle by
angle +- U95 before and after the adjustment, median U95, the median error of the measured angle,
and the drilled holes' true angle with the micro-plane controller in the loop and with metro's
(``simulate-log --controller metro``: the same seed drilled again, the cell turning the drill onto
``metrology.measure.surface.surface_normal`` with the CAD's shape operator). Everything from one
seeded Generator: the same arguments give the same table.

    nice -n 10 python benchmarks/study_measure.py --panel-known --calibrations 40 --holes 500 --seed 11 \
        --json benchmarks/results/measure_study_seed11.json [--heads table6] [--panels 'flat,wing (STEP)']

With ``--pose`` the log carries the robot's commanded pose (``pose_*`` columns, as ``metro
simulate-log`` writes them): the head's spin about the tool axis is then known, not a +-2 deg doubt.

The Table 2 head's beams point -z; it is studied in the frame turned 180 deg about x (beams +z), where
the forward simulator's poses face the datum: the geometry, and every angle, is the same.
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


def heads(rng):
    from metrology.core.layout import SensorLayout
    from metrology.core.paper import TABLE2_NOMINAL, TABLE6_NOMINAL, layout_from_table
    from metrology.sim.forward import draw_head

    flip = np.diag([1.0, -1.0, -1.0])
    t2 = layout_from_table(TABLE2_NOMINAL)
    t2 = SensorLayout(t2.names, t2.zero @ flip, t2.direction @ flip)
    t6 = layout_from_table(TABLE6_NOMINAL)
    three = draw_head(rng, 3).nominal
    return {"table2": t2, "table6": t6, "ring3": SensorLayout(three.names, three.zero, three.direction)}


def calibrate_head(rng, nominal, true, noise_mm, range_mm, n_poses, tilt_deg=14.0, scan="exact"):
    """The layout a calibration by metro gives (with covariance), from poses the forward simulator draws.

    ``scan``: ``exact`` (the true datum plane given), ``hand`` (the plane fitted to a hand-probe
    scan, forward.surface.sample_hand_scan, its covariance estimated with the sensors as
    ``metro calibrate`` does) or ``hand-exact`` (the same scan's plane taken as exact)."""
    from dataclasses import replace
    from types import SimpleNamespace

    from metrology.calibration.calibrate import with_datum
    from metrology.calibration.estimators import calibrate
    from metrology.core.frames import plane_in_tcs
    from metrology.core.observations import Observations
    from metrology.sim.forward import draw_poses, flat_surface, sample_hand_scan

    surface = flat_surface(np.zeros(3), np.array([0.0, 0.0, 1.0]))
    z0 = float(-np.mean(true.zero[:, 2]))
    rot, trans, hits = draw_poses(rng, surface, true.zero, true.direction, n_poses, tilt_max_rad=np.radians(tilt_deg),
                                  range_mm=range_mm, z0_mm=z0)
    d = hits.d + rng.normal(0.0, noise_mm, hits.d.shape)
    n_dat, off_dat, cov4 = surface.normal, -float(surface.normal @ surface.origin), None
    if scan != "exact":
        from metrology.datum import fit_plane_robust

        fit = fit_plane_robust(sample_hand_scan(surface, rng)[0])
        n_dat, off_dat, cov4 = fit.plane.normal, fit.plane.offset, fit.covariance
    normal, offset = plane_in_tcs(n_dat, off_dat, rot, trans)
    nominal = replace(nominal, noise_mm=np.full(nominal.n, noise_mm), range_mm=np.tile(range_mm, (nominal.n, 1)))
    cal = calibrate(nominal, Observations(normal, offset, d), "lsq")
    if scan == "hand":
        export = SimpleNamespace(d=d, tcs2tracker_rot=rot, tcs2tracker_trans=trans)
        ds = SimpleNamespace(export=export, plane=SimpleNamespace(normal=n_dat, offset=off_dat), plane_cov=cov4)
        cal = with_datum(cal, ds)
    return cal.layout


def run(args):
    import pyarrow as pa

    from metrology.measure.holes import Settings, measure_batch
    from metrology.measure.normals import hole_normals
    from metrology.sim.forward import perturb_layout
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.panels import make_panel

    rng = np.random.default_rng(args.seed)
    out = {"args": vars(args), "rows": []}
    range_mm = np.array([30.0, 70.0])
    panels = [p for p in [("flat", None), ("sphere", args.radius), ("cylinder", args.radius)] if p[0] in args.panels]
    for hname, nominal in heads(rng).items():
        for kind, R in panels:
            t0 = time.perf_counter()
            hits = {"before": [], "after": [], "before_nobound": [], "after_nobound": []}
            u95 = {"before": [], "after": []}
            for c in range(args.calibrations):
                true = perturb_layout(rng, nominal)
                true = true.with_params(true.zero, true.direction, noise_mm=np.full(true.n, args.noise),
                                        range_mm=np.tile(range_mm, (true.n, 1)))
                cal = calibrate_head(rng, nominal, true, args.noise, range_mm, args.poses, scan=args.scan)
                axis = (np.cos(a := rng.uniform(0, np.pi)), np.sin(a), 0.0)
                panel = make_panel(kind, R, axis=axis) if R else make_panel(kind)
                spec = LogSpec(true_layout=true, cell_layout=cal, panel=panel, spin_rad=np.pi)
                chunk = next(simulate_cell(spec, int(rng.integers(2**31)), 0, args.holes, chunk_holes=args.holes))
                cols = {"hole_id": [f"h{i}" for i in range(chunk.n)]}
                for j, s in enumerate(cal.names):
                    cols[f"d_{s}"] = chunk.d[:, j]
                    cols[f"d_{s}_after"] = chunk.d_after[:, j]
                table = pa.table(cols)
                b = measure_batch(cal, table, Settings(min_radius_mm=R or np.inf))
                for when, ang, U, truth, d in (("before", b.angle_before, "U95_angle_deg", chunk.true_angle, chunk.d),
                                               ("after", b.angle_after, "U95_after_deg", chunk.true_after,
                                                chunk.d_after)):
                    U = np.radians(b.columns.column(U).to_numpy(zero_copy_only=False))
                    ok = np.isfinite(ang) & np.isfinite(U)
                    hits[when].append(np.abs(ang - truth)[ok] <= U[ok])
                    u95[when].append(U[ok])
                    if R:  # the same holes, U95 without the curvature term: what the bias does
                        full = ok & np.all(np.isfinite(d), axis=1)
                        h = hole_normals(cal, d[full], min_radius_mm=np.inf)
                        hits[when + "_nobound"].append(np.abs(h.angle - truth[full]) <= h.U95)
            row = {"head": hname, "panel": kind, "radius_mm": R, "calibrations": args.calibrations,
                   "seconds": round(time.perf_counter() - t0, 1)}
            for k, v in hits.items():
                if v:
                    per = np.array([x.mean() for x in v])  # per calibration: holes share one calibration
                    allh = np.concatenate(v)
                    row[f"coverage_{k}"] = float(allh.mean())
                    row[f"coverage_{k}_se"] = float(per.std(ddof=1) / np.sqrt(len(per)))
                    row[f"holes_{k}"] = int(allh.size)
            for k, v in u95.items():
                row[f"median_U95_{k}_deg"] = float(np.degrees(np.median(np.concatenate(v))))
            out["rows"].append(row)
            print(_line(row), flush=True)
    return out


#: the ``--panel-known`` panels: (name in the table, kind, radius mm or the bundled CAD file); the analytic
#: ones (metrology.sim.forward.panels) get a grid mesh of their own surface as CAD and random drill points,
#: the generated ones (metrology.sim.forward.shapes) their bundled CAD (metrology/data/panels) and hole table
KNOWN_PANELS = (("flat", "flat", None), ("sphere R 500", "sphere", 500.0), ("cylinder R 500", "cylinder", 500.0),
                ("cylinder R 1000", "cylinder", 1000.0), ("saddle", "saddle", "saddle.stl"),
                ("wing (mesh)", "wing", "wing.stl"), ("wing (STEP)", "wing", "wing.step"),
                ("barrel (concave)", "barrel", "barrel.stl"), ("nacelle", "nacelle", "nacelle.stl"))


def _known_log(rng, kind, R, spec_kw, holes, cal, axis_groups, bundled, pose=False):
    """One calibration's holes on one panel: ``(chunk, metro's chunk, log table, HoleSurfaces)``, the
    chunks drilled by the same seed with the micro-plane controller and with metro's
    (``simulate-log --controller metro``: the same holes, readings and noise before the adjustment).

    Analytic panels: ``axis_groups`` groups of holes, each on its own panel turned to a random azimuth
    (a cylinder's axis at any azimuth to the head), its CAD a grid mesh of its own surface, the table
    its drill points; with ``pose`` the log carries the commanded pose (``pose_*`` columns, as
    metrology/sim/forward/log_write.py logs it: the head's spin is known). Generated panels: the
    bundled hole table drilled in order (cycled), the log as ``metro simulate-log`` writes it
    (``point_id``, the commanded pose), the bundled CAD's surfaces."""
    from dataclasses import replace

    import pyarrow as pa

    from metrology.io.holelog_schema import CELL, PANEL, TIME_S
    from metrology.jobs.measure_panel import footprint_mm, panel_hole_surfaces
    from metrology.jobs.simulate_log import metro_controller
    from metrology.measure.panel import HoleSurfaces, HoleTable
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_spec import HoleChunk, LogSpec
    from metrology.sim.forward.log_write import log_table
    from metrology.sim.forward.panels import make_panel
    from tests.measure.panel_fixtures import panel_mesh

    metro = metro_controller()
    if kind in bundled:
        truth, table, cad_surf = bundled[kind]
        spec = LogSpec(true_layout=spec_kw["true"], cell_layout=cal, panel=truth, table=table, spin_rad=0.0)
        seed = int(rng.integers(2**31))
        ch = next(simulate_cell(spec, seed, 0, holes, chunk_holes=holes))
        loop = next(simulate_cell(replace(spec, controller=metro), seed, 0, holes, chunk_holes=holes))
        return ch, loop, log_table(ch), cad_surf(footprint_mm(cal))
    chunks, parts, loops = [], [], []
    edges = np.linspace(0, holes, axis_groups + 1).astype(int)
    for g in range(axis_groups):
        n = int(edges[g + 1] - edges[g])
        axis = (np.cos(a := rng.uniform(0, np.pi)), np.sin(a), 0.0)
        panel = make_panel(kind, R, axis=axis) if R else make_panel(kind)
        spec = LogSpec(true_layout=spec_kw["true"], cell_layout=cal, panel=panel, spin_rad=np.radians(2.0))
        seed = int(rng.integers(2**31))
        ch = next(simulate_cell(spec, seed, 0, n, chunk_holes=n))
        loops.append(next(simulate_cell(replace(spec, controller=metro), seed, 0, n, chunk_holes=n)))
        ids = tuple(f"h{int(edges[g]) + i}" for i in range(ch.n))
        P = ch.drill_point
        parts.append(panel_hole_surfaces(Panel(panel_mesh(panel, half_mm=400.0, step_mm=4.0)),
                                         HoleTable(ids, P, -panel.normal_at(P), "holes"), footprint_mm(cal), 0.5, 0.0,
                                         np.radians(2.0)))
        chunks.append(ch)
    ch, loop = HoleChunk.concat(chunks), HoleChunk.concat(loops)
    first = parts[0]
    surf = HoleSurfaces(tuple(i for p in parts for i in p.ids), *(np.concatenate([getattr(p, k) for p in parts])
                                                                   for k in ("normal", "shape", "k", "u_shape",
                                                                             "problem")),
                        first.source, first.spin, point=np.concatenate([p.point for p in parts]),
                        frame=np.concatenate([p.frame for p in parts]), higher=np.concatenate([p.higher for p in parts]))
    cols = {"hole_id": list(surf.ids), CELL: ["C1"] * ch.n, PANEL: ["P1"] * ch.n, TIME_S: np.arange(ch.n, dtype=float)}
    for j, s in enumerate(cal.names):
        cols[f"d_{s}"] = ch.d[:, j]
        cols[f"d_{s}_after"] = ch.d_after[:, j]
    if pose:  # the commanded pose, as metrology/sim/forward/log_write.py logs it
        for j, ax in enumerate("xyz"):
            cols[f"pose_r{ax}_deg"] = np.degrees(ch.pose_rotvec[:, j])
            cols[f"pose_{ax}_mm"] = ch.pose_origin[:, j]
    return ch, loop, pa.table(cols), surf


def _bundled_panels(names):
    """``{kind: (true panel, forward hole table, footprint -> HoleSurfaces)}`` for the generated panels in
    ``names``: the simulator drills the generated surface (metrology.sim.forward.shapes); metro measures
    with the bundled CAD file (mesh, or the STEP's B-rep) and hole table."""
    from metrology.io.data import data_path
    from metrology.jobs.measure_panel import panel_hole_surfaces
    from metrology.measure.panel import read_hole_table
    from metrology.panel.mesh import load_panel
    from metrology.sim.forward.holes import read_hole_table as sim_table
    from metrology.sim.forward.shapes import generated_panel

    out = {}
    for label, kind, cad in KNOWN_PANELS:
        if label not in names or not isinstance(cad, str):
            continue
        holes = data_path("panels", f"{kind}.holes.csv")
        panel, table = load_panel(str(data_path("panels", cad))), read_hole_table(holes)
        cache = {}

        def surfaces(foot, panel=panel, table=table, cache=cache):
            key = round(foot, 1)  # the footprint moves by um between calibrations: its surfaces do not
            if key not in cache:
                cache[key] = panel_hole_surfaces(panel, table, key, 0.5, 0.0, 0.0)
            return cache[key]

        out[label] = (generated_panel(kind), sim_table(holes), surfaces)
    return out


def run_panel(args):
    """``--panel-known``: see the module docstring."""
    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import perturb_layout

    rng = np.random.default_rng(args.seed)
    out = {"args": vars(args), "rows": []}
    range_mm = np.array([30.0, 70.0])
    names = [p[0] for p in KNOWN_PANELS] if args.panels == "all" else args.panels.split(",")
    unknown = set(names) - {p[0] for p in KNOWN_PANELS}
    if unknown:
        raise SystemExit(f"--panels: unknown {sorted(unknown)}; expected some of {[p[0] for p in KNOWN_PANELS]}")
    bundled = _bundled_panels(names)
    print(HEADER)
    print("|---|---|---|---|---|---|---|---|---|---|")
    for hi, (hname, nominal) in enumerate(heads(rng).items()):
        if hname not in args.heads.split(","):
            continue
        for pi, (label, kind, R) in enumerate(KNOWN_PANELS):
            if label not in names:
                continue
            t0 = time.perf_counter()
            # each row its own stream (seed, head, panel): a row is the same whichever rows run with it,
            # so the study can be split over processes (--heads, --panels) and its rows joined
            rng = np.random.default_rng([args.seed, hi, pi])
            acc = {k: [] for k in ("hit_b", "hit_a", "u_b", "u_a", "err", "drill_plane", "drill_metro",
                                    "normal_err", "loop_skipped")}
            for c in range(args.calibrations):
                true = perturb_layout(rng, nominal)
                true = true.with_params(true.zero, true.direction, noise_mm=np.full(true.n, args.noise),
                                        range_mm=np.tile(range_mm, (true.n, 1)))
                cal = calibrate_head(rng, nominal, true, args.noise, range_mm, args.poses)
                ch, loop, log, surf = _known_log(rng, label if label in bundled else kind,
                                           R if not isinstance(R, str) else None, {"true": true}, args.holes, cal,
                                           args.axis_groups if kind == "cylinder" else 1, bundled, args.pose)
                b = measure_batch(cal, log, Settings(surfaces=surf))
                t = b.columns
                ub = np.radians(t.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
                ua = np.radians(t.column("U95_after_deg").to_numpy(zero_copy_only=False).astype(float))
                okb = np.isfinite(b.angle_before) & np.isfinite(ub)
                oka = np.isfinite(b.angle_after) & np.isfinite(ua)
                acc["hit_b"].append(np.abs(b.angle_before - ch.true_angle)[okb] <= ub[okb])
                acc["hit_a"].append(np.abs(b.angle_after - ch.true_after)[oka] <= ua[oka])
                acc["u_b"].append(ub[okb])
                acc["u_a"].append(ua[oka])
                acc["err"].append(np.abs(b.angle_before - ch.true_angle)[okb])
                acc["drill_plane"].append(ch.true_after[ch.adjusted])
                acc["drill_metro"].append(loop.true_after[loop.adjusted])
                acc["loop_skipped"].append(~loop.adjusted)
                nrm = np.stack([t.column(f"normal_{k}").to_numpy(zero_copy_only=False).astype(float) for k in "xyz"], 1)
                cosang = np.abs(np.sum(nrm * ch.normal_tcs, axis=1))[okb]
                acc["normal_err"].append(np.arccos(np.clip(cosang, -1.0, 1.0)))
            cat = {k: np.concatenate(v) for k, v in acc.items()}
            per = {k: np.array([x.mean() for x in acc[k] if x.size]) for k in ("hit_b", "hit_a")}
            row = {"head": hname, "panel": label, "radius_mm": R if not isinstance(R, str) else None,
                   "cad": R if isinstance(R, str) else "grid mesh 4 mm", "calibrations": args.calibrations,
                   "seconds": round(time.perf_counter() - t0, 1), "holes": int(cat["hit_b"].size),
                   "holes_drilled": args.calibrations * args.holes}
            for k, name in (("hit_b", "before"), ("hit_a", "after")):
                row[f"coverage_{name}"] = float(cat[k].mean()) if cat[k].size else float("nan")
                row[f"coverage_{name}_se"] = float(per[k].std(ddof=1) / np.sqrt(len(per[k]))) if len(per[k]) > 1 else 0.0
            row["holes_not_adjusted_metro"] = int(cat.pop("loop_skipped").sum())
            for k in ("u_b", "u_a", "err", "drill_plane", "drill_metro", "normal_err"):
                row[f"median_{k}_deg"] = float(np.degrees(np.median(cat[k]))) if cat[k].size else float("nan")
            out["rows"].append(row)
            print(panel_line(row), flush=True)
    return out


HEADER = ("| head | panel | coverage before % | after % | median U95 before [deg] | after | median error of the "
          "measured angle [deg] | drilled, micro-plane in the loop: median [deg] | drilled, metro's normal: median "
          "[deg] | holes measured |")


def panel_line(row):
    """One ``--panel-known`` row as a Markdown table line (:data:`HEADER`)."""
    return (f"| {row['head']} | {row['panel']} | "
            f"{100 * row['coverage_before']:.1f} ± {100 * row['coverage_before_se']:.1f} | "
            f"{100 * row['coverage_after']:.1f} ± {100 * row['coverage_after_se']:.1f} | "
            f"{row['median_u_b_deg']:.4f} | {row['median_u_a_deg']:.4f} | {row['median_err_deg']:.4f} | "
            f"{row['median_drill_plane_deg']:.4f} | {row['median_drill_metro_deg']:.4f} | "
            f"{row['holes']} / {row['holes_drilled']} |")


def _line(r):
    def cov(k):
        return (f"{100 * r[f'coverage_{k}']:.1f} ± {100 * r[f'coverage_{k}_se']:.1f}" if f"coverage_{k}" in r else "-")

    return (f"| {r['head']} | {r['panel']}{'' if not r['radius_mm'] else ' R ' + format(r['radius_mm'], 'g')} | "
            f"{cov('before')} | {cov('after')} | {cov('before_nobound')} | {cov('after_nobound')} | "
            f"{r['median_U95_before_deg']:.4f} | {r['median_U95_after_deg']:.4f} | {r['holes_before']} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calibrations", type=int, default=40)
    ap.add_argument("--holes", type=int, default=500, help="holes per calibration")
    ap.add_argument("--poses", type=int, default=60, help="calibration poses")
    ap.add_argument("--noise", type=float, default=0.005, help="reading noise, mm (1 sigma)")
    ap.add_argument("--radius", type=float, default=500.0, help="curved panels' radius, mm")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--scan", choices=("exact", "hand", "hand-exact"), default="exact",
                    help="the calibration's datum: the true plane, a hand-probe scan's plane with its covariance "
                         "carried (as metro calibrate), or the same scan's plane taken as exact")
    ap.add_argument("--panels", default=None, help="comma-separated: flat, sphere, cylinder; with --panel-known "
                    "the row names of KNOWN_PANELS (e.g. 'flat,wing (STEP)') or 'all' (the default)")
    ap.add_argument("--heads", default="table2,table6,ring3", help="--panel-known: comma-separated heads")
    ap.add_argument("--axis-groups", type=int, default=10, help="--panel-known: each calibration's holes on a "
                    "cylinder fall in this many groups, each with its axis at its own random azimuth")
    ap.add_argument("--panel-known", action="store_true", help="measure with the panel's local surface known "
                    "(metro measure --panel --points)")
    ap.add_argument("--pose", action="store_true", help="with --panel-known: the log carries the commanded pose "
                    "(pose_* columns): the head's spin is known")
    args = ap.parse_args(argv)
    if args.panel_known:
        args.panels = args.panels or "all"
        out = run_panel(args)
        if args.json:
            args.json.write_text(json.dumps(out, indent=1, default=str))
        return
    args.panels = tuple((args.panels or "flat,sphere,cylinder").split(","))
    print("| head | panel | before: coverage % | after | before, no curvature term | after, no term | "
          "median U95 before [deg] | after | holes |")
    print("|---|---|---|---|---|---|---|---|---|")
    out = run(args)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()

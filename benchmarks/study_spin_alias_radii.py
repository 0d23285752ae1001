"""The unstated convention's alias rule at tight radii (issue 49 item 3): does ``angle ± U95`` still hold on the holes a
4-sensor head's redundant reading leaves on the cell's convention when the panel's radius is 50-300 mm, where the
CAD's terms beyond the quadratic turn with the head (``cos psi``, ``cos 3 psi``, ``cos 4 psi``, ...) and the alias
model (:func:`metrology.measure.spin_alias.alias_reach`: misfit and tilt each ``a + b cos 2 psi + c sin 2 psi`` from
fits at 0, 45 and 90 deg) may miss the alias?

Per head (12 by default): a true layout (``forward.head.perturb_layout`` of Table 6) and its calibration by metro
(``study_measure.calibrate_head``, 60 poses over a flat datum, 5 um noise), drawn **once** and used on every panel. Per
panel (``--panels``: ``cylinder:R`` a cylinder with its axis along the panel's x, ``sphere:R``, ``lip:r`` a torus lip of
tube radius r on a 600 mm ring, outer side: a nacelle's or a leading edge's nose, tight across and gentle along) and
per cell (``free``: the head's spin uniform within +-180 deg per hole; ``keep``: within +-2 deg, a cell that keeps
its convention without stating it): one log of ``--holes`` holes along the crest drawn by the forward simulator
(``metrology.sim.forward``; the truth its ``true_angle``), the CAD a grid mesh of its surface, measured by
``measure_batch`` without the pose and **without** ``--spin-deg`` (metro's default: ``spin_stated`` False).

Per row: holes judged (of holes x heads), U95 coverage of the true angle among them with a 95 % interval clustered by
head, the median over heads of each head's median U95 and error, the holes **left on the convention** (reason empty,
``HoleBatch.on_convention``) and how many of those lie wrong beyond U95, the holes the alias sent to every spin and
their coverage, the holes not measured with their reasons.

``--check-model``: for the holes left on the convention, the alias model's own check: the misfit and tilt fitted with
the head turned on a 2 deg grid over the half-turn (90 fits a hole) against the harmonic's values, and the alias reach
from the grid (the largest tilt change at a spin the fitted misfit admits) against the model's.

    nice -n 10 python benchmarks/study_spin_alias_radii.py --heads 12 --holes 200 --seed 6101 \
        --panels cylinder:50,cylinder:100,cylinder:200,cylinder:300,sphere:50,sphere:100,sphere:200,sphere:300,lip:50 \
        --json benchmarks/results/spin_alias_tight_radii_s6101.json

Results: benchmarks/results/spin_alias_tight_radii.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _one_blas_thread  # noqa: E402,F401

#: cells: the head's true spin, uniform within +- this many deg per hole
CELLS = {"free": 180.0, "keep": 2.0}


def make(kind: str, r: float):
    """The forward simulator's panel ``kind:r`` (module docstring) and the crest's half-span, mm."""
    from metrology.sim.forward.panels import make_panel
    from metrology.sim.forward.torus import TorusPanel

    if kind == "cylinder":
        return make_panel("cylinder", r, axis=(1.0, 0.0, 0.0)), 100.0
    if kind == "sphere":  # every point alike: a short crest keeps the footprint's disc on the grid mesh
        return make_panel("sphere", r), min(100.0, 0.25 * r)
    if kind == "lip":
        return TorusPanel(r, 600.0, "outer"), 100.0
    raise ValueError(f"panel {kind!r}: expected cylinder, sphere or lip")


def one_log(rng, panel, span, true, cal, holes, spins, mesh_step):
    """``(chunk, log without pose, HoleSurfaces unstated)`` of ``holes`` holes on ``panel``'s crest (``|t| <= span``),
    the head's spin per hole ``spins`` (rad)."""
    from metrology.jobs.measure_panel import footprint_mm, panel_hole_surfaces
    from metrology.measure.panel import HoleTable
    from metrology.panel.mesh import Panel
    from metrology.sim.forward.log import simulate_cell
    from metrology.sim.forward.log_spec import LogSpec
    from metrology.sim.forward.log_write import log_table
    from study_tight_radii import crest_table
    from tests.measure.panel_fixtures import panel_mesh

    table = crest_table(panel, span, holes)
    spec = LogSpec(true_layout=true, cell_layout=cal, panel=panel, table=table, spin_rad=np.radians(2.0),
                   spin_path=lambda h: spins[np.asarray(h) % holes])
    ch = next(simulate_cell(spec, int(rng.integers(2**31)), 0, holes, chunk_holes=holes))
    log = log_table(ch)
    log = log.drop_columns([c for c in log.column_names if c.startswith("pose_")])
    cad = Panel(panel_mesh(panel, half_mm=160.0, step_mm=mesh_step))
    surf = panel_hole_surfaces(cad, HoleTable(table.ids, table.points, table.feed, "holes"), footprint_mm(cal),
                               0.5, 0.0, np.radians(2.0))
    return ch, log, replace(surf, spin_stated=False)


def clustered(hits):
    """(p, lo, hi): pooled coverage, its 95 % interval with the holes clustered by head (as
    study_spin_convention_calibrated.clustered)."""
    from study_spin_convention_calibrated import clustered as c

    return c(hits)


def _grid_check(call, every: bool):
    """The alias model against the fit itself, per hole ``_alias`` saw (``every``) or kept on the convention (its reach
    under SPIN_ALIAS_SHARE of U95): the misfit and tilt fitted with the head turned on a 2 deg grid over the half-turn,
    the misfit's roots between grid points refined by two secant steps of fits, the reach the fits give (the largest
    tilt change from the tilt at the nearer end of +-spin, at a spin beyond it whose fitted misfit the reading admits:
    a root, or a grid point within SPIN_SIGMAS sd) against the model's, in U95; and the harmonic's largest miss of the
    misfit (in its sd) and of the tilt (in U95) over the grid."""
    from metrology.measure import spin as S
    from metrology.measure.spin_alias import _at, harmonic

    (sub, dd, shape, u_shape, spin, higher, h0), (psi_m, reach_m) = call
    U = h0.U95
    keep = np.arange(len(dd)) if every else np.flatnonzero(reach_m <= S.SPIN_ALIAS_SHARE * U)
    if not keep.size:
        return None
    dd, shape, u_shape, spin, U = dd[keep], shape[keep], u_shape[keep], spin[keep], U[keep]
    higher = None if higher is None else higher.rows(keep)
    k = len(dd)

    def fit(rows, psi):
        K, hi = S._spun(shape[rows], None if higher is None else higher.rows(rows), psi)
        return S._fit(sub, dd[rows], K, u_shape[rows], np.zeros(len(rows)), hi)[0]

    every_row = np.arange(k)
    grid = np.radians(np.arange(-90.0, 90.0, 2.0))
    fits = [fit(every_row, np.full(k, g)) for g in grid]
    rho = np.stack([f.residual for f in fits], 1)  # (k, g) mm
    tilt = np.stack([f.budget.tilt for f in fits], 1)  # (k, g, 2) rad
    i0, i45, i90 = [int(np.argmin(np.abs(grid - np.radians(a)))) for a in (0.0, 45.0, -90.0)]
    R = harmonic(rho[:, i0], rho[:, i45], rho[:, i90])
    T = harmonic(tilt[:, i0], tilt[:, i45], tilt[:, i90])
    sd = np.fmax(fits[i45].residual_sd, fits[i90].residual_sd)
    drho = np.max(np.abs(rho - np.stack([_at(R, np.full(k, g)) for g in grid], 1)), 1) / sd
    dtilt = np.max(np.linalg.norm(tilt - np.stack([_at(T, np.full(k, g)) for g in grid], 1), axis=2), 1) / U
    # the tilt at the nearer end of +-spin: fits at +spin and -spin
    ends = {+1: fit(every_row, spin).budget.tilt, -1: fit(every_row, -spin).budget.tilt}
    near = lambda psi: np.where((psi > 0)[:, None], ends[+1], ends[-1])  # noqa: E731
    ok = (np.abs(rho) <= S.SPIN_SIGMAS * sd[:, None]) & (np.abs(grid)[None, :] > spin[:, None])
    reach = np.zeros(k)
    for j, g in enumerate(grid):
        d = np.linalg.norm(tilt[:, j] - near(np.full(k, g)), axis=1)
        reach = np.where(ok[:, j], np.fmax(reach, d), reach)
    # the roots: a sign change between grid points (the half-turn wraps), refined
    nxt = np.roll(rho, -1, axis=1)
    h_i, g_i = np.nonzero(np.sign(rho) != np.sign(nxt))
    if h_i.size:
        g1 = grid[g_i]
        step = np.radians(2.0)
        psi = g1 + step * rho[h_i, g_i] / (rho[h_i, g_i] - nxt[h_i, g_i])
        a, ra = np.full(h_i.size, g1), rho[h_i, g_i]
        for _ in range(2):
            f = fit(h_i, psi)
            with np.errstate(invalid="ignore", divide="ignore"):
                new = psi - f.residual * (psi - a) / (f.residual - ra)
            a, ra = psi, f.residual
            psi = np.where(np.isfinite(new) & (np.abs(new - psi) < step), new, psi)
        f = fit(h_i, psi)
        psi = (psi + 0.5 * np.pi) % np.pi - 0.5 * np.pi
        good = (np.abs(f.residual) <= S.SPIN_SIGMAS * sd[h_i]) & (np.abs(psi) > spin[h_i])
        d = np.linalg.norm(f.budget.tilt - np.where((psi > 0)[:, None], ends[+1][h_i], ends[-1][h_i]), axis=1)
        np.maximum.at(reach, h_i[good], d[good])
    model = reach_m[keep] / U
    return {"misfit_model_err_sd": drho, "tilt_model_err_U95": dtilt, "reach_fits_U95": reach / U,
            "reach_model_U95": model}


def _spied(fn):
    """``(fn(), calls)``: ``fn`` run with :func:`metrology.measure.spin._alias` recorded (its arguments, its result)."""
    from metrology.measure import spin as S

    calls, real = [], S._alias

    def spy(*a):
        out = real(*a)
        calls.append((a, out))
        return out

    S._alias = spy
    try:
        return fn(), calls
    finally:
        S._alias = real


def run(args):
    from metrology.measure.holes import Settings, measure_batch
    from metrology.sim.forward import perturb_layout
    from study_measure import calibrate_head
    from study_tight_radii import all_heads

    nominal = all_heads(np.random.default_rng(args.seed))[args.head]
    range_mm = np.array([30.0, 70.0])
    heads = []
    for hd in range(args.heads):
        rng = np.random.default_rng([args.seed, hd])
        true = perturb_layout(rng, nominal, tuple(args.perturb_scale * np.array([0.1, 1.0])),
                              tuple(args.perturb_scale * np.array([0.1, 2.0])))
        true = true.with_params(true.zero, true.direction, noise_mm=np.full(true.n, args.noise),
                                range_mm=np.tile(range_mm, (true.n, 1)))
        heads.append((true, calibrate_head(rng, nominal, true, args.noise, range_mm, args.poses)))
    results = []
    for spec in args.panels.split(","):
        kind, r = spec.split(":")
        panel, span = make(kind, float(r))
        for cell in args.cells.split(","):
            t0 = time.perf_counter()
            hits, on_hits, alias_hits, U_med, err_med = [], [], [], [], []
            judged = on = on_wrong = alias_n = 0
            not_measured = Counter()
            checks = []
            for hd, (true, cal) in enumerate(heads):
                rng = np.random.default_rng([args.seed, hd, int(float(r)), list(CELLS).index(cell), 7])
                spins = rng.uniform(-1.0, 1.0, args.holes) * np.radians(CELLS[cell])
                ch, log, surf = one_log(rng, panel, span, true, cal, args.holes, spins, args.mesh_step)
                b, calls = _spied(lambda cal=cal, log=log, surf=surf: measure_batch(cal, log, Settings(surfaces=surf)))
                U = np.radians(b.columns.column("U95_angle_deg").to_numpy(zero_copy_only=False).astype(float))
                ok = np.isfinite(b.angle_before) & np.isfinite(U)
                err = np.abs(b.angle_before - ch.true_angle)
                hit = err <= U
                reasons = b.columns.column("reason").to_pylist()
                aliased = np.array(["cannot tell it from a spin of" in (x or "") for x in reasons])
                # left on the convention: the before-readings' judgment (HoleBatch.on_convention is the after's
                # where the after-readings were judged); every hole here is on the convention unless sent to every spin
                conv = ok & np.array(["covers every spin" not in (x or "") for x in reasons])
                hits.append(hit[ok])
                on_hits.append(hit[conv])
                alias_hits.append(hit[ok & aliased])
                judged += int(ok.sum())
                on += int(conv.sum())
                on_wrong += int((conv & ~hit).sum())
                alias_n += int((ok & aliased).sum())
                if ok.any():
                    U_med.append(float(np.degrees(np.median(U[ok]))))
                    err_med.append(float(np.degrees(np.median(err[ok]))))
                for x in np.flatnonzero(~ok):
                    import re

                    not_measured[re.sub(r"[-+]?\d[\d.,]*(e[-+]?\d+)?", "#", reasons[x] or "")[:90]] += 1
                if args.check_model:
                    checks += [c for c in (_grid_check(x, args.check_every) for x in calls) if c is not None]
            p, lo, hi = clustered(hits)
            po, plo, phi = clustered(on_hits)
            row = {"panel": spec, "cell": cell, "holes": args.holes * args.heads, "judged": judged,
                   "coverage": p, "clustered_95": [lo, hi], "heads_min": float(min(h.mean() for h in hits if h.size)),
                   "median_U95_deg": float(np.median(U_med)) if U_med else None,
                   "median_err_deg": float(np.median(err_med)) if err_med else None,
                   "on_convention": on, "on_convention_wrong": on_wrong,
                   "on_convention_coverage": (on - on_wrong) / on if on else None,
                   "on_convention_clustered_95": [plo, phi],
                   "alias_sent": alias_n, "alias_coverage": float(np.concatenate(alias_hits).mean()) if alias_n else None,
                   "not_measured": dict(not_measured.most_common(4)),
                   "seconds": round(time.perf_counter() - t0, 1)}
            if checks:
                row["model_check"] = {k: {"max": float(np.max(np.concatenate([c[k] for c in checks]))),
                                          "median": float(np.median(np.concatenate([c[k] for c in checks])))}
                                      for k in checks[0]}
                g = np.concatenate([c["reach_fits_U95"] for c in checks])
                m = np.concatenate([c["reach_model_U95"] for c in checks])
                row["model_check"].update(holes=int(g.size), model_keeps=int((m <= 0.1).sum()),
                                          model_keeps_fits_over=int(((m <= 0.1) & (g > 0.1)).sum()),
                                          model_sends_fits_under=int(((m > 0.1) & (g <= 0.1)).sum()),
                                          fits_over_model_median=float(np.median(g[m > 0] / m[m > 0])) if (m > 0).any()
                                          else None)
            results.append(row)
            print(json.dumps(row), flush=True)
    return {"args": {k: str(v) for k, v in vars(args).items()}, "rows": results}


def table(rows) -> str:
    """The rows as the results page's markdown table."""
    head = ("| panel | cell | judged | coverage (clustered 95 %) | lowest head | median U95 deg | median error deg | "
            "left on the convention | of those wrong beyond U95 | sent to every spin by the alias (coverage) |\n"
            "|---|---|---|---|---|---|---|---|---|---|")
    out = [head]
    for r in rows:
        lo, hi = r["clustered_95"]
        ac = f" ({100 * r['alias_coverage']:.1f} %)" if r["alias_sent"] else ""
        out.append(f"| {r['panel']} | {r['cell']} | {r['judged']} of {r['holes']} | {100 * r['coverage']:.1f} % "
                   f"({100 * lo:.1f}-{100 * min(hi, 1.0):.1f}) | {100 * r['heads_min']:.1f} % | {r['median_U95_deg']:.4f} | "
                   f"{r['median_err_deg']:.4f} | {r['on_convention']} | {r['on_convention_wrong']} | {r['alias_sent']}{ac} |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--heads", type=int, default=12, help="calibrated heads (one calibration draw each)")
    ap.add_argument("--holes", type=int, default=200, help="holes per head's log")
    ap.add_argument("--head", default="table6", help="the nominal head (study_tight_radii.all_heads; 4 sensors)")
    ap.add_argument("--panels", default="cylinder:50,cylinder:100,cylinder:200,cylinder:300,sphere:50,sphere:100,"
                                        "sphere:200,sphere:300,lip:50", help="kind:radius_mm, comma separated")
    ap.add_argument("--cells", default="free,keep", help="free (spin within +-180 deg), keep (+-2 deg)")
    ap.add_argument("--poses", type=int, default=60, help="calibration poses")
    ap.add_argument("--noise", type=float, default=0.005, help="reading noise, mm (1 sigma)")
    ap.add_argument("--mesh-step", type=float, default=2.0, help="the CAD grid mesh's step, mm")
    ap.add_argument("--seed", type=int, default=6101)
    ap.add_argument("--check-model", action="store_true", help="the alias model against a 2 deg grid of fits")
    ap.add_argument("--check-every", action="store_true", help="check the model on every hole it saw, not only those "
                    "it kept on the convention")
    ap.add_argument("--perturb-scale", type=float, default=1.0, help="the true head's errors (perturb_layout's "
                    "ranges: 0.1-1 mm, 0.1-2 deg) times this (a better-made head: 0.1)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    out = run(args)
    print(table(out["rows"]))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()

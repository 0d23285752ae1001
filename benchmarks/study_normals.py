"""The study of issue 5: micro-plane against micro-sphere normals on curved panels.

    python benchmarks/study_normals.py [--points 60] [--seed 0] [--out study.md]

Error of each method (deg, against the analytic normal) as a function of the radius of
curvature, the tilt of the tool axis and the reading noise, for the paper's two layouts
(Table 6: 4 beams from z = -35 mm at 45 deg azimuths, pointing +z, crossing the axis 89 mm
ahead; Table 2: 4 beams from z = 0 at 0/90/180/270 deg azimuths, pointing -z, crossing
86.6 mm ahead). The layouts are the calibrated ones (nominal + the tables' errors), used
both to simulate and to compute, so the figures are the methods' own errors, not
calibration errors. Stand-off: the layouts' defaults (Table 6: 35 mm, Table 2: 43.3 mm).
Panels are meshed finely (0.5 mm grid; cylinders are ruled along y), drilling points
are uniform in the central 80 x 80 mm, the tilt azimuth is uniform.
Every table is printed as Markdown; same seed, same numbers.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from metrology.core.sphere import SPHERE_PRIOR_RADIUS_MM  # noqa: E402
from metrology.panel.mesh import Panel  # noqa: E402
from metrology.panel.points import DrillPoints  # noqa: E402
from metrology.panel.rays import RayCaster  # noqa: E402
from metrology.panel.run import run_normals  # noqa: E402
from metrology.panel.surfaces import ParametricSurface, panel_mesh  # noqa: E402
from metrology.core.paper import table2_layouts, table6_layouts  # noqa: E402

PANELS = {
    "flat": ("flat", math.inf),
    "cyl R3000": ("cylinder", 3000.0),
    "cyl R1500": ("cylinder", 1500.0),
    "cyl R800": ("cylinder", 800.0),
    "cyl R300": ("cylinder", 300.0),
    "sphere R800": ("sphere", 800.0),
    "sphere R300": ("sphere", 300.0),
    "saddle R800": ("saddle", 800.0),
}
LAYOUTS = {"Table 6": table6_layouts()[1], "Table 2": table2_layouts()[1]}

_cache = {}


def panel(name):
    if name not in _cache:
        kind, R = PANELS[name]
        surf = ParametricSurface(kind, R)
        sy = 5.0 if kind in ("flat", "cylinder") else 0.5
        mesh = panel_mesh(surf, 100.0, 100.0, 0.5, sy)
        p = Panel(mesh, name, [], surf)
        _cache[name] = (p, RayCaster(mesh, "auto").build())
    return _cache[name]


def run(name, layout, tilt_deg, noise, m, seed, loop=False, prior=SPHERE_PRIOR_RADIUS_MM):
    p, caster = panel(name)
    rng = np.random.default_rng([seed, sum(map(ord, name))])
    xy = rng.uniform(-40, 40, (m, 2))
    pts = np.column_stack([xy, p.surface.height(xy[:, 0], xy[:, 1])])
    drill = DrillPoints(pts, np.full_like(pts, np.nan), tuple(map(str, range(m))))
    r = run_normals(p, layout, drill, rng, tilt=math.radians(tilt_deg), noise=noise, loop=loop, caster=caster,
                       prior_radius_mm=prior)
    if not np.all(r.status == "ok"):
        raise RuntimeError(f"{name}: {dict(zip(*np.unique(r.status, return_counts=True)))}")
    return r


def f(e):
    e = np.degrees(e)
    return f"{e.mean():.4f} / {e.max():.4f}"


def table_radius(m, seed):
    out = []
    for noise in (0.0, 0.01):
        out.append(f"\n**Error vs radius of curvature** (tilt 2 deg, noise {noise} mm; mean / max over {m} points, deg)\n")
        out.append("| panel | " + " | ".join(f"{ln} plane | {ln} sphere" for ln in LAYOUTS) + " |")
        out.append("|---|" + "---|---|" * len(LAYOUTS))
        for name in PANELS:
            cells = []
            for layout in LAYOUTS.values():
                r = run(name, layout, 2.0, noise, m, seed)
                cells += [f(r.err_plane), f(r.err_sphere)]
            out.append(f"| {name} | " + " | ".join(cells) + " |")
    return out


def table_tilt(m, seed):
    out = ["\n**Error vs tilt** (noise 0.005 mm; mean / max, deg)\n"]
    tilts = (0.0, 0.5, 1.0, 2.0, 5.0)
    for ln, layout in LAYOUTS.items():
        out.append(f"\n{ln} layout\n")
        out.append("| panel | method | " + " | ".join(f"{t:g} deg" for t in tilts) + " |")
        out.append("|---|---|" + "---|" * len(tilts))
        for name in ("flat", "cyl R800", "cyl R300", "sphere R800", "saddle R800"):
            rs = [run(name, layout, t, 0.005, m, seed) for t in tilts]
            out.append(f"| {name} | plane | " + " | ".join(f(r.err_plane) for r in rs) + " |")
            out.append(f"| {name} | sphere | " + " | ".join(f(r.err_sphere) for r in rs) + " |")
    return out


def table_noise(m, seed):
    noises = (0.0, 0.002, 0.005, 0.01, 0.02)
    out = ["\n**Error vs reading noise** (tilt 1 deg; mean / max, deg; sphere: MAP with the 100 mm prior, "
           "sphere exact: the interpolating sphere, no prior)\n"]
    for ln, layout in LAYOUTS.items():
        out.append(f"\n{ln} layout\n")
        out.append("| panel | method | " + " | ".join(f"{s:g} mm" for s in noises) + " |")
        out.append("|---|---|" + "---|" * len(noises))
        for name in ("flat", "cyl R1500", "sphere R800", "sphere R300"):
            rs = [run(name, layout, 1.0, s, m, seed) for s in noises]
            rx = [run(name, layout, 1.0, s, m, seed, prior=math.inf) for s in noises]
            out.append(f"| {name} | plane | " + " | ".join(f(r.err_plane) for r in rs) + " |")
            out.append(f"| {name} | sphere | " + " | ".join(f(r.err_sphere) for r in rs) + " |")
            out.append(f"| {name} | sphere exact | " + " | ".join(f(r.err_sphere) for r in rx) + " |")
    return out


def table_symmetric(m, seed):
    """The nominal (symmetric) heads: four spots nearly concyclic, the sphere's worst case."""
    noms = {"Table 6 nominal": table6_layouts()[0], "Table 2 nominal": table2_layouts()[0]}
    out = ["\n**Symmetric heads** (the nominal layouts; tilt 1 deg; mean / max, deg)\n"]
    out.append("| panel | layout | noise (mm) | plane | sphere (100 mm prior) | sphere exact |")
    out.append("|---|---|---|---|---|---|")
    for name in ("flat", "sphere R800", "sphere R300", "cyl R800"):
        for ln, layout in noms.items():
            for noise in (0.0, 0.005):
                r = run(name, layout, 1.0, noise, m, seed)
                rx = run(name, layout, 1.0, noise, m, seed, prior=math.inf)
                out.append(f"| {name} | {ln} | {noise:g} | {f(r.err_plane)} | {f(r.err_sphere)} | {f(rx.err_sphere)} |")
    return out


def table_loop(m, seed):
    out = ["\n**Attitude loop** (initial tilt 3 deg, noise 0.005 mm, tolerance 0.5 deg, robot: 0.02 deg "
           "repeatability, 3 % rotation scale error, 0.05 mm TCP; adjustments mean / max, converged %, "
           "true final deviation mean / max deg)\n"]
    out.append("| panel | layout | plane: adjustments | plane: converged | plane: final dev | sphere: adjustments | sphere: converged | sphere: final dev |")
    out.append("|---|---|---|---|---|---|---|---|")
    for name in PANELS:
        for ln, layout in LAYOUTS.items():
            r = run(name, layout, 3.0, 0.005, m, seed, loop=True)
            cells = []
            for meth in ("plane", "sphere"):
                lp = r.loop[meth]
                cells += [f"{lp['iterations'].mean():.2f} / {lp['iterations'].max()}", f"{100 * lp['converged'].mean():.0f} %",
                          f(lp["final_dev"])]
            out.append(f"| {name} | {ln} | " + " | ".join(cells) + " |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=60)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    lines = [f"<!-- benchmarks/study_normals.py --points {a.points} --seed {a.seed} -->"]
    for fn in (table_radius, table_tilt, table_noise, table_symmetric, table_loop):
        lines += fn(a.points, a.seed)
        print("\n".join(lines[-1:]), file=sys.stderr)
    text = "\n".join(lines) + "\n"
    print(text)
    print(f"<!-- {time.perf_counter() - t0:.0f} s -->", file=sys.stderr)
    if a.out:
        from metrology.io.atomic import write_text

        write_text(a.out, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

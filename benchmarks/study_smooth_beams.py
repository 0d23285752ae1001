"""Beams on the facets against beams on the smooth surface the mesh tessellates (issue 14).

    python benchmarks/study_smooth_beams.py

The issue's case: a sphere cap R 500 mm meshed on a 400 x 400 grid over 500 mm (1.25 mm
cells, chord error <= 0.4 um), the paper's Table 6 head, tilt 3 deg, 49 drilling points
(7 x 7, 50 mm apart), no reading noise, no attitude loop; and the same on a cylinder R 300
and a saddle R 800. The reference is the analytic surface. Errors of both normals (deg,
mean / max) with the beams on the facets (``--beams facets``, the mesh as it is) and on
the smooth Phong surface (``--beams smooth``), in the same run.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from metrology.io.data import DATA_DIR  # noqa: E402
from metrology.io.layout import load_layout  # noqa: E402
from metrology.panel.mesh import Panel  # noqa: E402
from metrology.panel.points import DrillPoints  # noqa: E402
from metrology.panel.run import run_normals  # noqa: E402
from metrology.panel.surfaces import ParametricSurface, panel_mesh  # noqa: E402


def case(kind, R, beams, layout):
    surf = ParametricSurface(kind, R)
    mesh = panel_mesh(surf, 250.0, 250.0, 1.25)
    g = np.arange(-150.0, 151.0, 50.0)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    pts = np.c_[xy, surf.height(xy[:, 0], xy[:, 1])]
    drill = DrillPoints(pts, np.full_like(pts, np.nan), tuple(f"P{i}" for i in range(len(pts))))
    t0 = time.perf_counter()
    run = run_normals(Panel(mesh, kind, [], surf), layout, drill, np.random.default_rng(0), tilt=math.radians(3.0),
                      noise=0.0, loop=False, prior_radius_mm=math.inf, beams=beams)
    ok = run.status == "ok"
    return run.err_plane[ok], run.err_sphere[ok], int(ok.sum()), time.perf_counter() - t0


def main():
    layout = load_layout(DATA_DIR / "layout_table6.toml")
    print("Table 6 head, tilt 3 deg, 7 x 7 points 50 mm apart, no noise; 1.25 mm mesh; error mean / max (deg)\n")
    print("| surface | beams | points | micro-plane | micro-sphere | time (s) |")
    print("|---|---|---|---|---|---|")
    for kind, R in (("sphere", 500.0), ("cylinder", 300.0), ("saddle", 800.0)):
        for beams in ("facets", "smooth"):
            ep, es, n, dt = case(kind, R, beams, layout)
            ep, es = np.degrees(ep), np.degrees(es)
            print(f"| {kind} R{R:g} | {beams} | {n} | {ep.mean():.5f} / {ep.max():.5f} | {es.mean():.2e} / {es.max():.2e} "
                  f"| {dt:.2f} |")


if __name__ == "__main__":
    main()

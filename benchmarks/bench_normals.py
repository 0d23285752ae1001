"""Benchmark of ``metro normals``' ray casting (issue 5).

    python benchmarks/bench_normals.py [--points 10000] [--spacing 0.5]

On a doubly curved panel of ~1.3e6 triangles (sphere R 800 mm, 400 x 400 mm, 0.5 mm grid)
it measures, for each available ray engine (trimesh's pure-numpy engine, embree through
``embreex``, Open3D's ``RaycastingScene``), in the same run:

- the scene build time and the rays per second of the first-hit query;
- drilling points per second of the whole measurement (snap the points onto the panel,
  place the head, cast 4 beams, both normals; no attitude loop), including the build;
- the hit precision of the float32 engines against the double-precision recomputation,
  for the panel at the origin and moved to aircraft coordinates (x = 12.5 m), with and
  without the centring metro applies before handing vertices to Open3D.

The goal: 1e4 drilling points (4e4 rays) on a 1e6-triangle panel in under 2 s including
the scene build.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from metrology.panel.mesh import Panel  # noqa: E402
from metrology.panel.points import DrillPoints  # noqa: E402
from metrology.panel.rays import RayCaster, available_engines  # noqa: E402
from metrology.panel.run import run_normals  # noqa: E402
from metrology.panel.surfaces import ParametricSurface, panel_mesh  # noqa: E402
from metrology.core.paper import table6_layouts  # noqa: E402


def _rays(surf, m, rng, half=150.0):
    xy = rng.uniform(-half, half, (m, 2))
    o = np.column_stack([xy, surf.height(xy[:, 0], xy[:, 1]) + 60.0])
    d = np.tile([0.0, 0.0, -1.0], (m, 1)) + rng.normal(0, 0.3, (m, 3)) * [1, 1, 0]
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10_000)
    ap.add_argument("--spacing", type=float, default=0.5, help="grid step of the panel (mm)")
    ap.add_argument("--trimesh-rays", type=int, default=1000, help="rays for the slow pure-numpy engine")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    surf = ParametricSurface("sphere", 800.0)
    t0 = time.perf_counter()
    mesh = panel_mesh(surf, 200.0, 200.0, a.spacing)
    import os

    print(f"# {platform.machine()}, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; "
          f"{len(mesh.faces):,} triangles (generated in {time.perf_counter() - t0:.2f} s)")
    engines = available_engines()
    print(f"# engines available: {', '.join(engines)}")
    layout = table6_layouts()[1]
    n_rays = 4 * a.points
    o, d = _rays(surf, n_rays, rng)
    ref_t = None
    print("\n| engine | scene build (s) | rays | query + double refinement (s) | rays/s (engine only) | drilling points/s incl. build | 1e4 points incl. build (s) |")
    print("|---|---|---|---|---|---|---|")
    for eng in engines:
        m = a.trimesh_rays if eng == "trimesh" else n_rays
        caster = RayCaster(mesh, eng)
        t0 = time.perf_counter()
        caster.build()
        t_build = time.perf_counter() - t0
        t0 = time.perf_counter()
        tri, t, _ = caster.cast(o[:m], d[:m])
        t_q = time.perf_counter() - t0
        t0 = time.perf_counter()
        caster.first_triangle(o[:m], d[:m])
        t_raw = time.perf_counter() - t0
        if eng == "trimesh":
            ref_t = t
        # the whole measurement, from a fresh scene
        npts = a.points if eng != "trimesh" else a.trimesh_rays // 4
        xy = rng.uniform(-120, 120, (npts, 2))
        pts = np.column_stack([xy, surf.height(xy[:, 0], xy[:, 1])])
        drill = DrillPoints(pts, np.full_like(pts, np.nan), tuple(map(str, range(npts))))
        panel = Panel(mesh, "bench", [], surf)
        t0 = time.perf_counter()
        run = run_normals(panel, layout, drill, np.random.default_rng(1), tilt=math.radians(1.0), noise=0.005,
                             engine=eng, loop=False)
        t_all = time.perf_counter() - t0
        ok = int(np.sum(run.status == "ok"))
        print(f"| {eng} | {t_build:.3f} | {m:,} | {t_q:.3f} | {m / t_raw:,.0f} | {npts / t_all:,.0f} ({ok}/{npts} ok) | "
              f"{t_all * 1e4 / npts:.2f} |")
        if eng != "trimesh" and ref_t is not None:
            k = min(len(ref_t), m)
            same = np.isfinite(ref_t[:k]) & np.isfinite(t[:k])
            print(f"|  | refined hits vs trimesh (double): max |dt| = {np.max(np.abs(t[:k][same] - ref_t[:k][same])):.2e} mm over {int(same.sum())} rays | | | | | |")
    # float32 precision of the raw engine distances
    print("\n| panel position | centred before float32 | Open3D raw t_hit vs double: max error (um) | p99 (um) |")
    print("|---|---|---|---|")
    m = 20000
    for shift in (np.zeros(3), np.array([12500.0, 1800.0, 2400.0])):
        mesh_s = mesh.copy()
        mesh_s.apply_translation(shift)
        for centred in (True, False):
            caster = RayCaster(mesh_s, "open3d")
            if not centred:
                caster._centre = np.zeros(3)
            tri, t, _ = caster.cast(o[:m] + shift, d[:m])
            raw = caster.raw_distance(o[:m] + shift, d[:m])
            ok = np.isfinite(t) & np.isfinite(raw)
            err = np.abs(raw[ok] - t[ok]) * 1e3
            print(f"| {'origin' if not shift.any() else 'x = 12.5 m'} | {'yes' if centred else 'no'} | {err.max():.3f} | {np.percentile(err, 99):.3f} |")
    if "embree" in engines:
        caster = RayCaster(mesh, "embree").build()
        res = caster._impl._scene.run(o[:m], d[:m], output=1)
        tfar = np.asarray(res["tfar"], float) / caster._impl._scale if isinstance(res, dict) and "tfar" in res else None
        if tfar is not None:
            _, t, _ = caster.cast(o[:m], d[:m])
            ok = np.isfinite(t) & (tfar < 1e30)
            print(f"\nembree raw tfar vs double (panel at origin): max error {np.max(np.abs(tfar[ok] - t[ok])) * 1e3:.3f} um")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

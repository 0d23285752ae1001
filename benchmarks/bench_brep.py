"""Cost of the exact B-rep reference (OCP) per drilling point on a real STEP panel (issue 14).

    python benchmarks/bench_brep.py [--points 1000]

The panel: trimesh's ``models/BREP/base_interface_AP203.STEP`` (tests/data/meshes; 30
faces, in inches). Points are sampled on its coarse cascadio tessellation (default
tolerances, only to place the points); the B-rep reference
(:class:`metrology.panel.brep.BRepSurface`) is timed against the mesh reference
(:meth:`metrology.panel.mesh.Panel.reference_normal_at`, after the closest-point query) at
the same points, in the same run, and the two normals are compared.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from metrology.panel.brep import BRepSurface  # noqa: E402
from metrology.panel.mesh import Panel  # noqa: E402
from metrology.panel.points import snap_points  # noqa: E402
from metrology.panel.rays import RayCaster  # noqa: E402

STEP = ROOT / "tests" / "data" / "meshes" / "trimesh_base_interface_AP203.step"


def main(argv=None):
    import trimesh

    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=1000)
    a = ap.parse_args(argv)
    mesh = trimesh.load(STEP, force="mesh", process=False)  # cascadio's glTF: metres
    mesh.apply_scale(1000.0)
    mesh.merge_vertices()
    pts, face = trimesh.sample.sample_surface(mesh, a.points, seed=0)
    print(f"# {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}; {len(mesh.faces)} triangles")
    t = time.perf_counter()
    brep = BRepSurface(STEP)
    t_read = time.perf_counter() - t
    t = time.perf_counter()
    n_b = brep.normal(pts)
    t_b = time.perf_counter() - t
    panel = Panel(mesh, "ap203", [])
    caster = RayCaster(mesh, "auto").build()
    panel.edges()
    t = time.perf_counter()
    _, _, n_m, _, _ = snap_points(panel, caster, pts)
    t_m = time.perf_counter() - t
    ok = np.all(np.isfinite(n_b), axis=1)
    ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(n_b[ok] * n_m[ok], axis=1)), -1.0, 1.0)))
    print(f"B-rep: {brep.n_faces} faces, read {t_read:.2f} s; {a.points} points {t_b:.3f} s = "
          f"{1e3 * t_b / a.points:.3f} ms/point ({int(ok.sum())} found)")
    print(f"mesh reference (snap + crease-smoothed normal): {t_m:.3f} s = {1e3 * t_m / a.points:.4f} ms/point; "
          f"B-rep / mesh = {t_b / t_m:.0f} x")
    print(f"B-rep vs mesh reference: median {np.median(ang):.2e}, p95 {np.percentile(ang, 95):.2e}, "
          f"max {ang.max():.3f} deg")


if __name__ == "__main__":
    main()

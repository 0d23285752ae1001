"""Bias and spread of the micro-sphere against the micro-plane under reading noise (issue 14).

    python benchmarks/study_sphere_noise.py [--draws 2000] [--seed 0]

The spots are computed by the analytic ray-surface intersection (sphere, cylinder with
its axis across the tool axis, or saddle with principal radii +-R), not on a mesh, so the only errors are the methods' and the
noise's. One pose per row: the tool axis meets the surface at the layout's stand-off,
tilted 3 deg off the normal (fixed azimuth 30 deg); ``--draws`` noise draws per noise level
(Gaussian, 1 sigma per reading). Bias: angle between the mean measured normal and the
exact one; sd: RMS angle of the draws about their mean (deg). The micro-sphere uses the
default prior (radius 100 mm) with the true noise. Same seed, same table.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scipy.spatial.transform import Rotation  # noqa: E402

from metrology.core.normals import angle_between, micro_plane_normal  # noqa: E402
from metrology.core.paper import table2_layouts, table6_layouts  # noqa: E402
from metrology.core.sphere import micro_sphere_normal  # noqa: E402
from metrology.panel.head import default_standoff, tool_axis_tcs  # noqa: E402

SURFACES = [("sphere", 300.0), ("sphere", 800.0), ("cylinder", 300.0), ("cylinder", 800.0), ("saddle", 800.0)]
NOISE_UM = [0.0, 1.0, 5.0, 20.0]


def exact_readings(layout, kind, R, tilt, az):
    """Readings ``(n,)`` mm on the analytic surface, and its outward normal at the axis point (TCS)."""
    a = tool_axis_tcs(layout)
    z0 = float(np.mean(layout.zero @ a))
    P = a * (z0 + default_standoff(layout))
    rot = Rotation.from_rotvec(tilt * np.array([math.cos(az), math.sin(az), 0.0]))
    n_out = rot.apply(-a)
    C = P - R * n_out
    E, u = layout.zero, layout.direction
    if kind == "saddle":  # h = (s1^2 - s2^2) / 2R over the tangent plane at P (principal radii +-R)
        e1, e2 = rot.apply([1.0, 0.0, 0.0]), rot.apply([0.0, 1.0, 0.0])
        rel = E - P
        a1, a2, a3 = rel @ e1, rel @ e2, rel @ n_out
        b1, b2, b3 = u @ e1, u @ e2, u @ n_out
        qa, qb, qc = b1 * b1 - b2 * b2, 2 * (a1 * b1 - a2 * b2) - 2 * R * b3, a1 * a1 - a2 * a2 - 2 * R * a3
        disc = np.sqrt(qb * qb - 4 * qa * qc)
        roots = np.stack([(-qb - disc) / (2 * qa), (-qb + disc) / (2 * qa)])
        roots = np.where(roots > 0, roots, np.inf)
        return np.min(roots, axis=0), n_out
    if kind == "cylinder":  # axis: the tilted image of x, across the tool axis
        ax = rot.apply([1.0, 0.0, 0.0])
        E = E - np.outer((E - C) @ ax, ax) - C
        u_p = u - np.outer(u @ ax, ax)
        qa, qb, qc = np.sum(u_p * u_p, 1), np.sum(u_p * E, 1), np.sum(E * E, 1) - R * R
        return (-qb - np.sqrt(qb * qb - qa * qc)) / qa, n_out
    b = np.sum(u * (E - C), axis=1)
    c = np.sum((E - C) ** 2, axis=1) - R * R
    return -b - np.sqrt(b * b - c), n_out


def bias_sd(n, truth):
    m = n.mean(axis=0)
    m /= np.linalg.norm(m)
    return (math.degrees(angle_between(m, truth, oriented=True)),
            math.degrees(math.sqrt(np.mean(angle_between(n, m[None], oriented=True) ** 2))))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print("| layout | surface | noise um | plane bias / sd (deg) | sphere bias / sd (deg) |")
    print("|---|---|---|---|---|")
    for lname, layout in (("Table 6", table6_layouts()[1]), ("Table 2", table2_layouts()[1])):
        a = tool_axis_tcs(layout)
        for kind, R in SURFACES:
            d0, truth = exact_readings(layout, kind, R, math.radians(3.0), math.radians(30.0))
            for s_um in NOISE_UM:
                s = s_um * 1e-3
                d = d0[None] + rng.standard_normal((args.draws if s > 0 else 1, layout.n)) * s
                n_p = micro_plane_normal(layout.zero, layout.direction, d)
                n_s = micro_sphere_normal(layout.zero, layout.direction, d, axis=a, noise_mm=s)[0]
                bp, sp = bias_sd(n_p, truth)
                bs, ss = bias_sd(n_s, truth)
                print(f"| {lname} | {kind} R{R:g} | {s_um:g} | {bp:.4f} / {sp:.4f} | {bs:.4f} / {ss:.4f} |")


if __name__ == "__main__":
    main()

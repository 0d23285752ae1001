"""CAD stand-ins for the forward simulator's analytic panels, for tests and studies of
``metro measure --panel``: a grid mesh whose vertices lie on the simulator's surface (the CAD a
tessellator would write), and the hole table of a simulated log (its truth's drill points; the
feed against the panel's outward normal at them, as CAM exports it)."""

from __future__ import annotations

import csv

import numpy as np


def panel_mesh(panel, half_mm: float = 260.0, step_mm: float = 4.0, shift=(0.0, 0.0, 0.0)):
    """trimesh.Trimesh of ``panel`` (a :class:`metrology.sim.forward.panels.Panel`) over the square
    ``|x|, |y| <= half_mm``: its heights on a grid of ``step_mm``, two triangles a cell, faces
    toward ``+z`` (none where the surface has no height: beyond a cylinder's side); moved by ``shift`` (mm)."""
    import trimesh

    g = np.arange(-half_mm, half_mm + 0.5 * step_mm, step_mm)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = panel.height(X, Y)
    V = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1) + np.asarray(shift, float)
    m = len(g)
    i, j = np.meshgrid(np.arange(m - 1), np.arange(m - 1), indexing="ij")
    a = (i * m + j).ravel()
    b, c, d = a + m, a + m + 1, a + 1
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    off = ~np.all(np.isfinite(V), axis=1)  # beyond a cylinder's or sphere's side: no surface there
    F = F[~np.any(off[F], axis=1)]
    keep = np.zeros(len(V), bool)
    keep[F.ravel()] = True  # the vertices of a face only (an STL has no other): none left at the origin
    renum = np.cumsum(keep) - 1
    return trimesh.Trimesh(V[keep], renum[F], process=False)


def write_hole_table(truth_csv, out_csv, panel, rows=None):
    """``hole_id,x,y,z,i,j,k`` of the holes in ``truth_csv`` (all, or the ``rows``): the drill point and
    the feed ``-n`` (``n`` the panel's outward normal there). ``panel`` is the CAD: the drill point's
    ``z`` is its height at the truth's ``x, y`` (the truth's own where the CAD is the simulated panel)."""
    with open(truth_csv, newline="") as fh:
        rd = list(csv.DictReader(fh))
    if rows is not None:
        rd = [rd[r] for r in rows]
    P = np.array([[float(r["drill_x_mm"]), float(r["drill_y_mm"]), float(r["drill_z_mm"])] for r in rd])
    P[:, 2] = panel.height(P[:, 0], P[:, 1])
    n = panel.normal_at(P)
    with open(out_csv, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["hole_id", "x", "y", "z", "i", "j", "k"])
        for r, p, nn in zip(rd, P, n):
            w.writerow([r["hole_id"], *(f"{v:.6f}" for v in p), *(f"{-v:.9f}" for v in nn)])
    return out_csv

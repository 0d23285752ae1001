"""The robot's commanded pose in a hole log, and each hole against its CAD through it.

A cell that logs the pose before the adjustment (``pose_r{x,y,z}_deg``, the ``tcs2panel`` rotation as a
rotation vector, and ``pose_{x,y,z}_mm``, the TCS origin in the panel frame: metrology/sim/forward/log_write.py)
gives the head's spin about the tool axis, which puts the CAD's shape into the TCS without a convention
(:mod:`metrology.measure.spin`), and lets each measured normal and surface be compared with the CAD's.
"""

from __future__ import annotations

import numpy as np

from metrology.core.sym3 import smallest_eigvec
from metrology.io.holelog_schema import POSE_POSITION, POSE_ROTATION

__all__ = ["POSE_COLUMNS", "read_pose", "against_cad"]

POSE_COLUMNS = POSE_ROTATION + POSE_POSITION


def read_pose(table):
    """The log's commanded pose, or None without its columns: ``(tcs2panel (N, 3, 3), origin (N, 3) mm,
    panel frame)``; a row with no pose gets NaN (the whole row: a row is NaN or finite throughout)."""
    if not all(c in table.column_names for c in POSE_COLUMNS):
        return None
    from scipy.spatial.transform import Rotation

    v = np.column_stack([np.asarray(table.column(c).cast("float64").to_numpy(zero_copy_only=False), float)
                         for c in POSE_COLUMNS])
    ok = np.isfinite(v.sum(1))  # every one of the six finite
    if ok.all():  # the usual: no gather, no masked copy (each costs three times the rotations)
        return Rotation.from_rotvec(np.radians(v[:, :3])).as_matrix(), v[:, 3:]
    R = np.full((len(v), 3, 3), np.nan)
    if ok.any():
        R[ok] = Rotation.from_rotvec(np.radians(v[ok, :3])).as_matrix()
    return R, v[:, 3:]


#: rows per slice of :func:`against_cad` (its (n, rows) temporaries stay in the processor's cache, as
#: :data:`metrology.measure.surface.SLICE_ROWS`; each hole's numbers are its own, whatever the slice)
SLICE_ROWS = 16384


def against_cad(layout, d, normal, shape, surf, table_row, pose):
    """Each hole against its CAD: ``(angle (N,) rad, offset (N,) mm)``.

    ``angle``: between the measured normal (TCS, turned into the panel frame by the commanded pose)
    and the CAD's normal at the hole. ``offset``: where the readings put the surface on the drill
    axis (the spots, their height from the CAD's curvature taken off, fitted by a plane, met by the
    axis), against the table's nominal point, along the CAD's outward normal: a panel standing 1 mm
    proud of its CAD reads +1. NaN where a reading, the pose or the table row is missing."""
    N = len(d)
    if N <= SLICE_ROWS:
        return _against_cad(layout, d, normal, shape, surf, table_row, pose)
    ang, off = np.empty(N), np.empty(N)
    R, origin = pose
    for i in range(0, N, SLICE_ROWS):
        s = slice(i, i + SLICE_ROWS)
        ang[s], off[s] = _against_cad(layout, d[s], normal[s], shape[s], surf, table_row[s], (R[s], origin[s]))
    return ang, off


def _against_cad(layout, d, normal, shape, surf, table_row, pose):
    """:func:`against_cad` of one slice."""
    from metrology.measure.normals import drill_axis

    R, origin = pose
    N = len(d)
    ang, off = np.full(N, np.nan), np.full(N, np.nan)
    from metrology.measure.beyond import _finite_rows

    rows = np.flatnonzero((table_row >= 0) & _finite_rows(d) & _finite_rows(origin) & _finite_rows(normal))
    if rows.size == 0:
        return ang, off
    if rows.size == N:  # every row (the usual batch): views, not copies
        rows = slice(None)
    r = table_row[rows]
    ncad = surf.normal[r]  # outward (toward the head), panel frame
    Rr = R[rows]
    nr = normal[rows]
    # R n, along the drill axis (into the panel), dotted with the CAD's normal: explicit 3 x 3 over the holes
    cos = -sum((Rr[:, i, 0] * nr[:, 0] + Rr[:, i, 1] * nr[:, 1] + Rr[:, i, 2] * nr[:, 2]) * ncad[:, i] for i in range(3))
    ang[rows] = np.arccos(np.clip(cos, -1.0, 1.0))
    a = drill_axis(layout)
    # the spots, sensor-major (n, h) per component, mm, TCS
    dT = np.ascontiguousarray(d[rows].T)  # (n, h): each op over contiguous rows
    E, u = layout.zero, layout.direction
    sx, sy, sz = (E[:, k, None] + dT * u[:, k, None] for k in range(3))
    sa = sx * a[0] + sy * a[1] + sz * a[2]
    lx, ly, lz = sx - sa * a[0], sy - sa * a[1], sz - sa * a[2]  # lateral
    K = shape[rows]
    k00, k01, k02, k11, k12, k22 = (np.ascontiguousarray(K[:, i, j]) for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)))
    sag = 0.5 * ((k00 * lx + 2.0 * (k01 * ly + k02 * lz)) * lx + (k11 * ly + 2.0 * k12 * lz) * ly
                 + k22 * lz * lz)  # away from the head
    sx, sy, sz = sx - sag * a[0], sy - sag * a[1], sz - sag * a[2]
    cx, cy, cz = sx.mean(0), sy.mean(0), sz.mean(0)
    xc, yc, zc = sx - cx, sy - cy, sz - cz
    # the plane through them: the smallest eigenvector of their scatter (the SVD's last right singular vector)
    m = smallest_eigvec((xc * xc).sum(0), (xc * yc).sum(0), (xc * zc).sum(0), (yc * yc).sum(0), (yc * zc).sum(0),
                        (zc * zc).sum(0), a)
    t = (cx * m[:, 0] + cy * m[:, 1] + cz * m[:, 2]) / (m @ a)
    Ra = Rr[:, :, 0] * a[0] + Rr[:, :, 1] * a[1] + Rr[:, :, 2] * a[2]  # the drill axis in the panel frame
    o, p = origin[rows], surf.point[r]  # the axis's hit (o + t Ra) from the nominal point, along the CAD's normal
    off[rows] = sum((o[:, i] + t * Ra[:, i] - p[:, i]) * ncad[:, i] for i in range(3))
    return ang, off

"""Drilling points: read from CSV, laid on a grid, snapped onto the panel."""

from __future__ import annotations

import math
from dataclasses import dataclass
import numpy as np
from metrology.panel.mesh import Panel, panel_plane
from metrology.panel.rays import RayCaster


@dataclass(frozen=True)
class DrillPoints:
    """Drilling points as given (before snapping).

    Attributes
    ----------
    points : (m, 3) float, mm, panel frame
    approach : (m, 3) float, unit, panel frame, the tool feed direction (into the panel);
        NaN rows where not given (then the feed is the inward surface normal)
    labels : tuple of str, length m (``line 7`` for CSV rows, ``grid i,j`` for a grid)
    """

    points: np.ndarray
    approach: np.ndarray
    labels: tuple


def read_points(path) -> DrillPoints:
    """Read drilling points from a CSV: ``x,y,z`` (mm) and optionally ``i,j,k`` (approach).

    A header row of names is optional; blank lines and lines starting with ``#`` are
    skipped. The approach direction is the tool feed (into the panel) and is normalised.

    Raises
    ------
    ValueError
        Naming the file, the line and the value.
    """
    from metrology.io.export import read_csv_rows

    path = str(path)
    rows = read_csv_rows(path, "points")
    pts, app, labels = [], [], []
    ncol = None
    for lineno, row in enumerate(rows, start=1):
        cells = [c.strip() for c in row]
        if not cells or all(c == "" for c in cells) or cells[0].startswith("#"):
            continue
        if not pts and ncol is None and not _is_number(cells[0]):
            names = [c.lower() for c in cells]
            if names[:3] != ["x", "y", "z"] or names[3:] not in ([], ["i", "j", "k"]):
                raise ValueError(f"{path}: line {lineno}: header must be x,y,z or x,y,z,i,j,k, got {','.join(cells)}")
            ncol = len(names)
            continue
        if len(cells) not in (3, 6) or (ncol is not None and len(cells) != ncol):
            raise ValueError(f"{path}: line {lineno}: expected {ncol or '3 or 6'} columns (x,y,z[,i,j,k]), got {len(cells)}")
        try:
            vals = [float(c) for c in cells]
        except ValueError:
            bad = next(c for c in cells if not _is_number(c))
            raise ValueError(f"{path}: line {lineno}: {bad!r} is not a number") from None
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"{path}: line {lineno}: values must be finite, got {','.join(cells)}")
        pts.append(vals[:3])
        if len(vals) == 6:
            a = np.array(vals[3:])
            na = np.linalg.norm(a)
            if na == 0:
                raise ValueError(f"{path}: line {lineno}: approach direction is the zero vector")
            app.append(a / na)
        else:
            app.append([np.nan] * 3)
        labels.append(f"line {lineno}")
    if not pts:
        raise ValueError(f"{path}: no drilling points")
    return DrillPoints(np.array(pts, float), np.array(app, float), tuple(labels))


def _is_number(text) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def grid_points(panel: Panel, spacing: float, caster: RayCaster, footprint_mm=None, with_dropped=False):
    """A regular grid of drilling points over the panel.

    The grid (step ``spacing`` mm) lies in the panel's best-fit plane; each node is
    projected onto the mesh along the plane normal; nodes whose projection misses the
    panel are dropped. With ``footprint_mm`` (the head's footprint radius, mm), so are the
    nodes whose footprint would hold a crease, a hole or the panel's outline
    (:meth:`Panel.edges`): the head stays on one smooth region.

    Returns
    -------
    DrillPoints, and with ``with_dropped`` also the number of nodes dropped for their footprint
    """
    if not (spacing > 0 and math.isfinite(spacing)):
        raise ValueError(f"grid spacing must be a positive number of mm, got {spacing}")
    centre, B = panel_plane(panel.mesh)
    uv = (np.asarray(panel.mesh.vertices) - centre) @ B[:2].T
    lo, hi = uv.min(0), uv.max(0)
    nu = np.floor((hi - lo) / spacing).astype(int)
    if np.prod(nu + 1) > 1_000_000:
        raise ValueError(f"grid spacing {spacing} mm gives {int(np.prod(nu + 1))} points over the panel; use a coarser grid (at most 1e6)")
    off = lo + ((hi - lo) - nu * spacing) / 2.0
    iu, iv = np.meshgrid(np.arange(nu[0] + 1), np.arange(nu[1] + 1), indexing="ij")
    u = off[0] + iu.ravel() * spacing
    v = off[1] + iv.ravel() * spacing
    h = float(np.ptp((np.asarray(panel.mesh.vertices) - centre) @ B[2])) + 1.0
    origins = centre + u[:, None] * B[0] + v[:, None] * B[1] + (h + 1.0) * B[2]
    tri, t, _ = caster.cast(origins, np.tile(-B[2], (len(u), 1)))
    hit = tri >= 0
    pts = origins[hit] - t[hit, None] * B[2]
    labels = np.array([f"grid {a},{b}" for a, b in zip(iu.ravel()[hit], iv.ravel()[hit])], dtype=object)
    if not len(pts):
        raise ValueError(f"{panel.source}: no grid point of spacing {spacing} mm falls on the panel")
    dropped = 0
    if footprint_mm is not None:
        near, _, _ = panel.edges().near(pts, float(footprint_mm))
        keep = np.ones(len(pts), bool)
        keep[near] = False
        dropped = int((~keep).sum())
        pts, labels = pts[keep], labels[keep]
        if not len(pts):
            raise ValueError(f"{panel.source}: every grid point of spacing {spacing} mm has a crease, a hole or the "
                             f"panel's edge within the head's footprint ({footprint_mm:.1f} mm)")
    drill = DrillPoints(pts, np.full_like(pts, np.nan), tuple(labels))
    return (drill, dropped) if with_dropped else drill


def snap_points(panel: Panel, caster: RayCaster, points):
    """Snap drilling points onto the mesh.

    Parameters
    ----------
    points : (m, 3) float, mm, panel frame

    Returns
    -------
    snapped : (m, 3) float, mm, panel frame, the closest points on the mesh
    distance : (m,) float, mm, how far each point was from the mesh
    normal : (m, 3) float, unit, panel frame, the mesh's reference normal
        (:meth:`Panel.reference_normal_at`: the face, smoothed within the crease angle), out
    faceting : (m,) float, rad, that normal's own uncertainty (see there)
    chord_mm : (m,) float, mm, the faceting's chord error there
    """
    import trimesh

    tri, snapped = caster.closest(points)
    bary = trimesh.triangles.points_to_barycentric(np.asarray(panel.mesh.triangles)[tri], snapped)
    bary = np.clip(bary, 0.0, 1.0)
    bary /= bary.sum(1, keepdims=True)
    n, faceting, chord = panel.reference_normal_at(tri, bary)
    return snapped, np.linalg.norm(snapped - points, axis=1), n, faceting, chord

"""Mesh panels for the hole-log simulator: a CAD file (STL, OBJ, PLY, GLB; STEP through cascadio)
behind the :class:`~metrology.sim.forward.panels.Panel` interface, beams ray-cast onto it; and
the generated panels' exports (binary STL) with their hole tables.

Ray casting: Open3D's ``RaycastingScene`` (loaded by :func:`metrology.io._o3d.open3d`, in float32,
on vertices centred on the mesh's bounding box) finds the triangle each ray hits first; the
distance is then recomputed in float64 on that triangle's plane (``t = n.(v0 - e) / n.u``), so
the hit is exact to the mesh and the same on every machine. A ray that misses, or meets a
triangle from its back (the inside of the panel), is NaN. The outward normal at a point is the
mesh's vertex normals interpolated over its nearest triangle (smooth shading, as the surface the
mesh was made from); the faces are wound so their normals point to the head's side
(:meth:`MeshPanel.oriented`: the side most of the hole table's feeds come from; without a table,
``+z``).

The shape operator the *cell* computes from a mesh CAD (``shape_at``): a quadric
``w = a s^2 + b s t + c t^2 + d s + e t + g`` fitted by least squares to the mesh's vertices within
:data:`QUADRIC_RADIUS_MM` of the point, in the frame of the interpolated normal; ``S = -hess w``
projected on the tangent plane. Nothing here knows the measurement's formulas.

Generated panels are exported with a binary-STL header ``metro-sim panel=<name> half_mm=<h>``:
:func:`load_sim_panel` then gives the analytic surface as the truth (the faceted mesh is only the
CAD), so the truth is the smooth surface the mesh was made from.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from metrology.sim.forward.panels import Panel

__all__ = ["MeshPanel", "load_sim_panel", "panel_mesh", "write_stl", "generated_holes", "write_holes_csv",
           "write_generated", "PLAUSIBLE_DIAGONAL_MM", "QUADRIC_RADIUS_MM"]

#: a panel whose bounding-box diagonal is outside this (mm) is not in mm (metres, microns?)
PLAUSIBLE_DIAGONAL_MM = (20.0, 50_000.0)
#: the neighbourhood of a mesh CAD's local quadric (mm)
QUADRIC_RADIUS_MM = 25.0
#: STEP tessellation (OpenCASCADE through cascadio): chord tolerance (mm) and angle (rad)
STEP_TOL_LINEAR_MM = 1e-3
STEP_TOL_ANGULAR_RAD = 5e-3
_HEADER = re.compile(r"metro-sim panel=(\w+) half_mm=([0-9.eE+-]+)")


class MeshPanel(Panel):
    """A triangle mesh (mm, panel frame) as a panel: ray-cast hits, smooth normals, local quadrics.

    Parameters
    ----------
    vertices : (v, 3) float, mm, panel frame
    faces : (f, 3) int, wound so that the face normals point to the head's side
    source : str, where it came from (for messages)
    """

    kind = "mesh"

    def __init__(self, vertices, faces, source="<mesh>"):
        import trimesh

        self.mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
        self.source = str(source)
        self.V = np.asarray(self.mesh.vertices, float)
        self.F = np.asarray(self.mesh.faces, np.int64)
        self.face_normal = np.asarray(self.mesh.face_normals, float)
        self.vertex_normal = np.asarray(self.mesh.vertex_normals, float)
        lo, hi = self.V.min(0), self.V.max(0)
        self.centre = (lo + hi) / 2
        self.diagonal_mm = float(np.linalg.norm(hi - lo))
        self._scene = None
        self._tree = None

    # ------------------------------------------------------------------ Open3D scene (lazy)
    def _o3d_scene(self):
        if self._scene is None:
            from metrology.io._o3d import open3d

            o3d = open3d()
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(o3d.core.Tensor((self.V - self.centre).astype(np.float32)),
                                o3d.core.Tensor(self.F.astype(np.uint32)))
            self._scene = (o3d, scene)
        return self._scene

    def _first_triangle(self, e, u):
        o3d, scene = self._o3d_scene()
        rays = np.concatenate([e - self.centre, u], axis=1).astype(np.float32)
        ans = scene.cast_rays(o3d.core.Tensor(rays))
        tri = ans["primitive_ids"].numpy().astype(np.int64)
        return np.where(tri == np.iinfo(np.uint32).max, -1, tri)

    def intersect(self, origin, direction):
        e = np.asarray(origin, float)
        u = np.asarray(direction, float)
        shape = np.broadcast_shapes(e.shape, u.shape)[:-1]
        e, u = np.broadcast_to(e, shape + (3,)).reshape(-1, 3), np.broadcast_to(u, shape + (3,)).reshape(-1, 3)
        t = np.full(len(e), np.nan)
        ok = np.all(np.isfinite(e), 1) & np.all(np.isfinite(u), 1)
        if ok.any():
            tri = self._first_triangle(e[ok], u[ok])
            hit = tri >= 0
            idx = np.flatnonzero(ok)[hit]
            n = self.face_normal[tri[hit]]
            v0 = self.V[self.F[tri[hit], 0]]
            nu = np.sum(n * u[idx], 1)
            with np.errstate(invalid="ignore", divide="ignore"):
                th = np.sum(n * (v0 - e[idx]), 1) / nu
            t[idx] = np.where((nu < 0) & (th >= 0), th, np.nan)  # entering from the head's side
        return t.reshape(shape)

    def _closest(self, points):
        """Nearest triangle ``(m,)`` and barycentric coordinates ``(m, 3)`` of ``points (m, 3)`` mm."""
        import trimesh

        o3d, scene = self._o3d_scene()
        q = o3d.core.Tensor((points - self.centre).astype(np.float32))
        tri = scene.compute_closest_points(q)["primitive_ids"].numpy().astype(np.int64)
        tris = self.V[self.F[tri]]
        bary = trimesh.triangles.points_to_barycentric(tris, points)
        bary = np.clip(bary, 0.0, 1.0)
        return tri, bary / bary.sum(1, keepdims=True)

    def normal_at(self, points):
        p = np.asarray(points, float)
        flat = p.reshape(-1, 3)
        out = np.full(flat.shape, np.nan)
        ok = np.all(np.isfinite(flat), 1)
        if ok.any():
            tri, bary = self._closest(flat[ok])
            n = np.einsum("mk,mkj->mj", bary, self.vertex_normal[self.F[tri]])
            out[ok] = n / np.linalg.norm(n, axis=1, keepdims=True)
        return out.reshape(p.shape)

    def height(self, x, y):
        """``z`` mm where a vertical ray meets the mesh; NaN off it."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        top = self.V[:, 2].max() + 1.0
        e = np.stack([x.ravel(), y.ravel(), np.full(x.size, top)], axis=-1)
        t = self.intersect(e, np.array([0.0, 0.0, -1.0]))
        return (top - t).reshape(x.shape)

    def shape_at(self, points):
        from scipy.spatial import cKDTree

        p = np.asarray(points, float).reshape(-1, 3)
        if self._tree is None:
            self._tree = cKDTree(self.V)
        n = self.normal_at(p)
        out = np.full((len(p), 3, 3), np.nan)
        for m, (q, nm) in enumerate(zip(p, n)):
            near = self._tree.query_ball_point(q, QUADRIC_RADIUS_MM)
            if len(near) < 6 or not np.all(np.isfinite(nm)):
                continue
            k = int(np.argmin(np.abs(nm)))
            e1 = np.eye(3)[k] - nm[k] * nm
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(nm, e1)
            d = self.V[near] - q
            s, t, w = d @ e1, d @ e2, d @ nm
            A = np.stack([s * s, s * t, t * t, s, t, np.ones_like(s)], axis=1)
            a, b, c = np.linalg.lstsq(A, w, rcond=None)[0][:3]
            B = np.stack([e1, e2])  # (2, 3)
            out[m] = -B.T @ np.array([[2 * a, b], [b, 2 * c]]) @ B
        return out

    def check_patch(self, half_mm):
        super().check_patch(half_mm)
        x = np.array([-half_mm, half_mm, half_mm, -half_mm, 0.0])
        y = np.array([-half_mm, -half_mm, half_mm, half_mm, 0.0])
        if not np.all(np.isfinite(self.height(x, y))):
            raise ValueError(f"{self.source}: the patch of half side {half_mm:g} mm about the origin is not all on "
                             "the panel; give a smaller --patch-mm")

    def to_dict(self):
        return {"kind": self.kind, "source": self.source, "faces": int(len(self.F))}

    def oriented(self, feed_points=None, feed=None):
        """This panel facing the head: with a hole table (``feed_points (m, 3)`` mm, ``feed (m, 3)``), wound so
        that most feeds enter it (``feed . n < 0``); without, so that its area-weighted mean normal has
        ``z >= 0`` (the head works on ``+z``). Returns self or a copy with the winding reversed."""
        if feed is not None:
            into = np.sum(self.normal_at(feed_points) * feed, axis=1)
            flip = np.mean(into > 0) > 0.5
        else:
            flip = float(np.sum(self.face_normal[:, 2] * np.asarray(self.mesh.area_faces))) < 0
        return MeshPanel(self.V, self.F[:, ::-1], self.source) if flip else self


def _check_diagonal(diag, source):
    lo, hi = PLAUSIBLE_DIAGONAL_MM
    if not (lo <= diag <= hi):
        raise ValueError(f"{source}: bounding-box diagonal {diag:.4g}, expected {lo:g}..{hi:g} mm "
                         "(is the panel in metres or inches? panels are read in mm)")


def load_sim_panel(path):
    """``(truth, cad)`` panels of a panel file: a generated panel's export (STL header ``metro-sim panel=``)
    gives its analytic surface for both (the truth is the smooth surface the mesh was made from);
    any other file is ray-cast as its mesh. STEP needs the ``step`` extra (cascadio).

    Raises
    ------
    ValueError
        One line naming the file: unreadable, empty, not in mm, STEP without the extra.
    """
    import trimesh

    path = str(path)
    if not Path(path).is_file():
        raise ValueError(f"{path}: no such panel file")
    is_step = path.lower().endswith((".step", ".stp"))
    kw = {"tol_linear": STEP_TOL_LINEAR_MM, "tol_angular": STEP_TOL_ANGULAR_RAD} if is_step else {}
    if is_step:
        try:
            import cascadio  # noqa: F401
        except ImportError:
            raise ValueError(f"{path}: reading STEP needs the step extra (pip install 'metro[step]': cascadio)") from None
    try:
        mesh = trimesh.load(path, force="mesh", process=False, **kw)
    except Exception as exc:  # trimesh raises many types for a bad file
        raise ValueError(f"{path}: cannot read the panel ({type(exc).__name__}: {' '.join(str(exc).split())[:100]})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: the panel has no triangles")
    if is_step:
        mesh.apply_scale(1000.0)  # OpenCASCADE hands the STEP over in metres
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"{path}: the panel's vertices hold NaN or infinite coordinates")
    header = mesh.metadata.get("header", "") if isinstance(mesh.metadata, dict) else ""
    m = _HEADER.search(header or "")
    V = np.asarray(mesh.vertices, float)
    _check_diagonal(float(np.linalg.norm(np.ptp(V, axis=0))), path)
    if m:
        from metrology.sim.forward.shapes import generated_panel

        panel = generated_panel(m.group(1), float(m.group(2)))
        return panel, panel
    mesh.merge_vertices()
    keep = mesh.nondegenerate_faces(height=1e-9)
    mesh.update_faces(keep)
    if len(mesh.faces) == 0:
        raise ValueError(f"{path}: every triangle of the panel is degenerate")
    panel = MeshPanel(mesh.vertices, mesh.faces, path)
    return panel, panel


def panel_mesh(panel, half_mm: float, spacing_mm: float):
    """A regular triangulation ``(vertices (v, 3) mm, faces (f, 3))`` of ``panel.height`` over
    ``|x|, |y| <= half_mm`` at ``spacing_mm``, wound with normals to ``+z`` (the head's side)."""
    k = int(round(2 * half_mm / spacing_mm))
    if k < 2:
        raise ValueError(f"spacing {spacing_mm} mm: at least 2 cells across {2 * half_mm} mm")
    g = np.linspace(-half_mm, half_mm, k + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), panel.height(X.ravel(), Y.ravel())], axis=-1)
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    a = (i * (k + 1) + j).ravel()
    b, c, d = a + (k + 1), a + (k + 1) + 1, a + 1
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


def write_stl(path, vertices, faces, header: str):
    """A binary STL (float32, mm) with an 80-byte ``header``, written atomically."""
    from metrology.io.atomic import atomic_path

    V, F = np.asarray(vertices, float), np.asarray(faces)
    tri = V[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rec = np.zeros(len(F), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["n"], rec["v"] = n, tri
    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header.encode("ascii")[:80].ljust(80, b" "))
            fh.write(np.uint32(len(F)).tobytes())
            fh.write(rec.tobytes())


def generated_holes(panel, margin_mm: float = 75.0, spacing_mm: float = 25.0, prefix: str = "H"):
    """The hole table of a generated panel: a grid of ``spacing_mm`` over ``|x|, |y| <= half - margin``,
    the points on the (CAD) surface and the feed ``-n`` into it.

    Returns
    -------
    ids : list of str, ``<prefix><4 digits>``
    points : (m, 3) float, mm, panel frame
    feed : (m, 3) float, unit, panel frame
    """
    lim = panel.half_mm - margin_mm
    if lim < 0:
        raise ValueError(f"panel {2 * panel.half_mm:g} mm wide has no room for holes {margin_mm:g} mm from its edge")
    k = int(math.floor(2 * lim / spacing_mm + 1e-9))
    g = -lim + (2 * lim - k * spacing_mm) / 2 + spacing_mm * np.arange(k + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    x, y = X.ravel(), Y.ravel()
    P = np.stack([x, y, panel.height(x, y)], axis=-1)
    feed = -panel.normal_at(P)
    ids = [f"{prefix}{i + 1:04d}" for i in range(len(x))]
    return ids, P, feed


def write_holes_csv(path, ids, points, feed):
    """``hole_id,x,y,z,i,j,k`` (mm, unit), 6 and 9 decimals, written atomically."""
    from metrology.io.atomic import atomic_path

    lines = ["hole_id,x,y,z,i,j,k"]
    for h, p, f in zip(ids, points, feed):
        lines.append(f"{h},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},{f[0]:.9f},{f[1]:.9f},{f[2]:.9f}")
    with atomic_path(Path(path)) as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")


def write_generated(name: str, folder, half_mm: float = 125.0, spacing_mm: float = 10.0, hole_margin_mm: float = 75.0,
                    hole_spacing_mm: float = 25.0) -> tuple:
    """Write the generated panel ``name`` as ``<folder>/<name>.stl`` (the CAD, ``spacing_mm`` grid) and its
    hole table ``<folder>/<name>.holes.csv``; returns the two paths. Large panels: a larger ``half_mm``,
    a finer ``spacing_mm``."""
    from metrology.sim.forward.shapes import generated_panel

    panel = generated_panel(name, half_mm)
    folder = Path(folder)
    V, F = panel_mesh(panel, half_mm, spacing_mm)
    stl, csv = folder / f"{name}.stl", folder / f"{name}.holes.csv"
    write_stl(stl, V, F, f"metro-sim panel={name} half_mm={half_mm:g} spacing_mm={spacing_mm:g}")
    write_holes_csv(csv, *generated_holes(panel, hole_margin_mm, hole_spacing_mm))
    return stl, csv

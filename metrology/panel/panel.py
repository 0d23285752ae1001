"""Normals on curved CAD panels: micro-plane against micro-sphere, and the attitude loop.

The pipeline of ``metro normals`` (issue 5), as pure functions on arrays plus two small
objects (:class:`Panel`, :class:`RayCaster`):

1. :func:`load_panel` reads a mesh (trimesh: STL, OBJ, PLY, GLB/GLTF; STEP with the
   ``cascadio`` wheel), repairs what can be repaired and refuses the rest.
2. Drilling points come from a CSV (:func:`read_points`) or a grid (:func:`grid_points`) and
   are snapped onto the mesh (:func:`snap_points`).
3. The head is placed (:func:`place_head`): its tool axis (the TCS feed axis, ``+z`` when the
   beams point ``+z`` as in the paper's Table 6, ``-z`` when they point ``-z`` as in Table 2)
   passes through the drilling point, along the inward surface normal tilted by the attitude
   error, at the *stand-off*: the distance along the tool axis from the sensor-zero plane
   (the plane perpendicular to the axis through the mean zero point) to the drilling point.
4. The beams are cast onto the mesh (:class:`RayCaster`; any engine finds the triangle, the
   hit is then recomputed in double precision on that triangle), readings get noise.
5. Two estimates of the normal (TCS, then panel frame): the micro-plane (Eqs. 17-19, the
   least-squares plane for other than 4 sensors, :func:`metrology.normals.micro_plane_normal`)
   and the micro-sphere (:func:`micro_sphere_normal`: the algebraic sphere through the spots,
   normal where the tool axis meets it; it degrades smoothly to the plane as the radius
   goes to infinity).
6. The attitude loop (Eqs. 20-22, :func:`attitude_loop`) with a robot motion-error model
   (:class:`MotionError`).

Frames: the *panel frame* is the mesh's frame (mm). The TCS is the layout's frame (mm);
``R`` (tcs2panel rotation) and ``T`` (TCS origin in the panel frame) place it:
``p_panel = R p_tcs + T``. Normals of the surface point out of the panel towards the head
(the side the faces' normals point to).
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.core.normals import angle_between, attitude_angles, micro_plane_normal, projection_points, rot_x, rot_y

__all__ = [
    "ParametricSurface",
    "panel_mesh",
    "Panel",
    "load_panel",
    "RayCaster",
    "available_engines",
    "DrillPoints",
    "read_points",
    "grid_points",
    "snap_points",
    "tool_axis_tcs",
    "default_standoff",
    "place_head",
    "tilted_feed",
    "cast_beams",
    "fit_algebraic_sphere",
    "micro_sphere_normal",
    "MotionError",
    "attitude_loop",
    "NormalsRun",
    "run_normals",
    "summarize",
    "STATUS",
]

# --- tolerances of this module, each with its unit -------------------------------------

#: a drilling point farther than this from the mesh is "off the panel" (mm)
ON_PANEL_MM = 1.0
#: bounding-box diagonal outside this interval: warn "is the panel in mm?" (mm)
PLAUSIBLE_DIAGONAL_MM = (20.0, 50_000.0)
#: the micro-sphere's prior on curvature: 1 sigma of the curvature is 1 / this (mm). It
#: decides, given the reading noise, how much evidence a curvature needs before it is
#: believed; it picks the plane where the spots do not determine the curvature at all
SPHERE_PRIOR_RADIUS_MM = 100.0
#: noise floor of the spots used by that prior when the reading noise is 0 (mm): mesh
#: tessellation and float rounding
SPHERE_NOISE_FLOOR_MM = 1e-4
#: a root of the axis/sphere quadratic is taken as the plane root when |A| is below this
#: (unitless, scaled coordinates)
SPHERE_FLAT_A = 1e-12
#: the tool axis of a layout is +-z; the mean beam direction must make at most this angle
#: with it (deg)
AXIS_MAX_DEG = 60.0
#: largest initial attitude error accepted (rad): beyond it the head is no longer a head
#: looking at the panel
MAX_TILT = math.radians(45.0)
#: attitude loop: at most this many adjustments per point
MAX_ADJUSTMENTS = 10
#: STEP tessellation (OpenCASCADE through cascadio): chord tolerance (mm) and angular
#: deflection (rad); 1 um chords keep the tessellation error far under reading noise
STEP_TOL_LINEAR_MM = 1e-3
STEP_TOL_ANGULAR_RAD = 5e-3

#: per-point status codes, in order of precedence
STATUS = {
    "ok": "measured",
    "off_panel": "drilling point is farther than the tolerance from the panel",
    "approach_behind": "approach direction points out of the panel (head behind the panel)",
    "beam_miss": "a beam missed the panel",
    "beam_behind": "a beam hit the panel from behind",
    "out_of_range": "a reading is outside the sensor's range",
}


# --- parametric panels ----------------------------------------------------------------


@dataclass(frozen=True)
class ParametricSurface:
    """A generated panel: a height field ``z = h(x, y)`` through the origin, normal ``+z`` there.

    Attributes
    ----------
    kind : {"flat", "cylinder", "sphere", "saddle"}
        ``cylinder``: convex, axis along ``y``, radius ``radius``; ``sphere``: convex cap;
        ``saddle``: ``z = (x^2 - y^2) / (2 radius)`` (principal radii +-radius at the origin).
    radius : float, mm (ignored for ``flat``)
    """

    kind: str
    radius: float = math.inf

    def __post_init__(self):
        if self.kind not in ("flat", "cylinder", "sphere", "saddle"):
            raise ValueError(f"panel kind must be flat, cylinder, sphere or saddle, got {self.kind!r}")
        if self.kind != "flat" and not (self.radius > 0 and math.isfinite(self.radius)):
            raise ValueError(f"{self.kind} panel needs a finite positive radius, got {self.radius}")

    @property
    def tag(self) -> str:
        """The header tag written into generated STL files (read back by :func:`load_panel`)."""
        return f"metro-panel kind={self.kind}" + ("" if self.kind == "flat" else f" radius_mm={self.radius:g}")

    def height(self, x, y):
        """``z`` (mm) at ``x, y`` (mm, panel frame), any matching shapes."""
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        R = self.radius
        if self.kind == "flat":
            return np.zeros(np.broadcast(x, y).shape)
        if self.kind == "cylinder":
            return np.sqrt(R * R - x * x) - R + 0.0 * y
        if self.kind == "sphere":
            return np.sqrt(R * R - x * x - y * y) - R
        return (x * x - y * y) / (2.0 * R)

    def normal(self, points):
        """Analytic unit normals.

        Parameters
        ----------
        points : (m, 3) float, mm, panel frame, on the surface (only x, y are used)

        Returns
        -------
        n : (m, 3) float, unit, panel frame, pointing out (``+z`` side)
        """
        p = np.atleast_2d(np.asarray(points, float))
        x, y = p[:, 0], p[:, 1]
        z = self.height(x, y)
        R = self.radius
        if self.kind == "flat":
            g = np.column_stack([np.zeros_like(x), np.zeros_like(x), np.ones_like(x)])
        elif self.kind == "cylinder":
            g = np.column_stack([x, np.zeros_like(x), z + R])
        elif self.kind == "sphere":
            g = np.column_stack([x, y, z + R])
        else:
            g = np.column_stack([-x / R, y / R, np.ones_like(x)])
        return g / np.linalg.norm(g, axis=1, keepdims=True)

    def max_half_width(self) -> float:
        """Largest half-width (mm) a square panel can have with a valid height field."""
        if self.kind in ("cylinder", "sphere"):
            return 0.65 * self.radius if self.kind == "sphere" else 0.9 * self.radius
        return math.inf


def panel_mesh(surface: ParametricSurface, half_x: float, half_y: float, spacing: float, spacing_y=None):
    """Triangulate ``surface`` over ``[-half_x, half_x] x [-half_y, half_y]`` (mm).

    Parameters
    ----------
    surface : ParametricSurface
    half_x, half_y : float, mm
    spacing : float, mm, grid step in x
    spacing_y : float, mm, grid step in y (default ``spacing``); a cylinder with its axis
        along y is ruled, so a coarse y step costs nothing in accuracy.

    Returns
    -------
    trimesh.Trimesh
        Faces wound so that their normals point out (+z side); vertex normals are set to
        the analytic normals.
    """
    import trimesh

    spacing_y = spacing if spacing_y is None else spacing_y
    if spacing <= 0 or spacing_y <= 0 or half_x <= 0 or half_y <= 0:
        raise ValueError(f"panel_mesh: sizes must be positive, got half {half_x}, {half_y}, spacing {spacing}, {spacing_y}")
    limit = surface.max_half_width()
    if math.hypot(half_x, half_y) >= (surface.radius if surface.kind == "sphere" else math.inf) or half_x >= (limit if surface.kind == "cylinder" else math.inf):
        raise ValueError(f"panel_mesh: a {surface.kind} of radius {surface.radius} mm cannot span +-{half_x} x +-{half_y} mm")
    nx = max(1, int(math.ceil(2 * half_x / spacing)))
    ny = max(1, int(math.ceil(2 * half_y / spacing_y)))
    x = np.linspace(-half_x, half_x, nx + 1)
    y = np.linspace(-half_y, half_y, ny + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), surface.height(X, Y).ravel()])
    idx = np.arange(V.shape[0]).reshape(nx + 1, ny + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    mesh = trimesh.Trimesh(V, F, process=False)
    mesh.vertex_normals = surface.normal(V)
    return mesh


def write_binary_stl(mesh, path, header: str = "") -> None:
    """Write ``mesh`` as a binary STL with an 80-byte ``header`` text, atomically."""
    from metrology.io.atomic import atomic_path

    dtype = np.dtype([("normal", "<f4", 3), ("tri", "<f4", (3, 3)), ("attr", "<u2")])
    rec = np.zeros(len(mesh.faces), dtype=dtype)
    rec["normal"] = mesh.face_normals
    rec["tri"] = mesh.triangles
    head = header.encode("ascii")[:80].ljust(80, b" ")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(head)
            fh.write(np.uint32(len(rec)).tobytes())
            fh.write(rec.tobytes())


# --- the panel --------------------------------------------------------------------------


@dataclass
class Panel:
    """A loaded, validated panel mesh.

    Attributes
    ----------
    mesh : trimesh.Trimesh, mm, panel frame; faces consistently wound, normals out
    source : str, where it came from (for messages)
    warnings : list of str, things repaired or suspicious (printed by the CLI)
    surface : ParametricSurface or None, the analytic surface when the file says so
    """

    mesh: object
    source: str = "<mesh>"
    warnings: list = field(default_factory=list)
    surface: ParametricSurface | None = None

    def vertex_normal_at(self, tri, bary):
        """Interpolated vertex normals.

        Parameters
        ----------
        tri : (m,) int, face indices (no misses)
        bary : (m, 3) float, barycentric coordinates

        Returns
        -------
        n : (m, 3) float, unit, panel frame
        """
        vn = np.asarray(self.mesh.vertex_normals)[np.asarray(self.mesh.faces)[tri]]  # (m, 3, 3)
        n = np.einsum("mk,mkj->mj", bary, vn)
        return n / np.linalg.norm(n, axis=1, keepdims=True)


def _surface_from_header(text: str):
    m = re.search(r"metro-panel kind=(\w+)(?: radius_mm=([0-9.eE+-]+))?", text or "")
    if not m:
        return None
    try:
        return ParametricSurface(m.group(1), float(m.group(2)) if m.group(2) else math.inf)
    except ValueError:
        return None


def load_panel(path) -> Panel:
    """Load and validate a panel mesh (units mm).

    STEP files are tessellated by OpenCASCADE (the ``cascadio`` wheel) with 1 um chords
    (:data:`STEP_TOL_LINEAR_MM`) and converted from the intermediate glTF's metres to mm.

    A panel is an open surface, not a solid: it is refused only when it is empty, when its
    faces are all degenerate, or when its winding is inconsistent and cannot be repaired.
    Degenerate and duplicate faces are dropped and reported in ``warnings``; a bounding
    box outside :data:`PLAUSIBLE_DIAGONAL_MM` adds a warning (not in mm?).

    Raises
    ------
    ValueError
        With the file name and what was wrong.
    """
    import trimesh

    path = str(path)
    is_step = path.lower().endswith((".step", ".stp"))
    kw = {"tol_linear": STEP_TOL_LINEAR_MM, "tol_angular": STEP_TOL_ANGULAR_RAD} if is_step else {}
    try:
        loaded = trimesh.load(path, force="mesh", process=False, **kw)
    except ImportError:
        raise ValueError(f"{path}: reading STEP needs the cascadio wheel (pip install cascadio)") from None
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except (ValueError, KeyError, IndexError, TypeError, NotImplementedError, OSError) as exc:
        raise ValueError(f"{path}: cannot read mesh ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})") from None
    except Exception as exc:  # trimesh raises its own types for unknown formats
        raise ValueError(f"{path}: cannot read mesh ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f"{path}: the mesh is empty (no triangles)")
    mesh = loaded
    warnings = []
    if is_step:
        # cascadio tessellates in the file's unit (mm) and hands over a glTF, which is in
        # metres by specification: back to mm
        mesh.apply_scale(1000.0)
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"{path}: vertices contain NaN or infinite coordinates")
    n0 = len(mesh.faces)
    mesh.merge_vertices()
    keep = mesh.nondegenerate_faces(height=1e-9) & mesh.unique_faces()
    if not np.any(keep):
        raise ValueError(f"{path}: all {n0} faces are degenerate (zero area)")
    if not np.all(keep):
        mesh.update_faces(keep)
        mesh.remove_unreferenced_vertices()
        warnings.append(f"{path}: dropped {n0 - int(keep.sum())} degenerate or duplicate faces of {n0}")
    if not mesh.is_winding_consistent:
        try:
            trimesh.repair.fix_winding(mesh)
        except ImportError:
            raise ValueError(f"{path}: inconsistently oriented faces; repairing them needs networkx (pip install networkx)") from None
        if not mesh.is_winding_consistent:
            raise ValueError(f"{path}: inconsistently oriented faces that cannot be repaired (non-manifold edges?)")
        warnings.append(f"{path}: face winding was inconsistent and has been repaired")
    diag = float(np.linalg.norm(mesh.extents))
    lo, hi = PLAUSIBLE_DIAGONAL_MM
    if not lo <= diag <= hi:
        warnings.append(f"{path}: bounding-box diagonal {diag:.4g} is implausible for a panel in mm (expected {lo:g}..{hi:g} mm); is it in m or inch?")
    header = mesh.metadata.get("header", "") if isinstance(mesh.metadata, dict) else ""
    return Panel(mesh, path, warnings, _surface_from_header(header))


# --- ray casting --------------------------------------------------------------------------


def available_engines() -> list:
    """The ray engines usable here, among ``trimesh``, ``embree``, ``open3d``."""
    out = ["trimesh"]
    try:
        from trimesh.ray import has_embree

        if has_embree:
            out.append("embree")
    except ImportError:
        pass
    try:
        from metrology.io._o3d import open3d

        open3d()
        out.append("open3d")
    except (ImportError, OSError):
        pass
    return out


#: ``auto`` picks the first available of these, ordered by the benchmark
#: (benchmarks/bench_normals.py: Open3D's RaycastingScene is fastest including its build)
AUTO_ORDER = ("open3d", "embree", "trimesh")


class RayCaster:
    """First hits of rays on a mesh, by one engine, refined in double precision.

    The engine only finds the triangle; :meth:`cast` then intersects the ray with that
    triangle in float64 (Moeller-Trumbore), so the float32 engines (embree, Open3D) give
    the same hit points as the double-precision one wherever they find the same triangle.
    Open3D works on coordinates centred on the mesh (float32 keeps 7 digits).
    """

    def __init__(self, mesh, engine: str = "auto"):
        engines = available_engines()
        if engine == "auto":
            engine = next(e for e in AUTO_ORDER if e in engines)
        if engine not in ("trimesh", "embree", "open3d"):
            raise ValueError(f"engine must be auto, trimesh, embree or open3d, got {engine!r}")
        if engine not in engines:
            raise ValueError(f"ray engine {engine!r} is not available here (available: {', '.join(engines)})")
        self.mesh = mesh
        self.engine = engine
        self._tri = np.asarray(mesh.triangles, dtype=float)
        self._centre = np.asarray(mesh.bounds, float).mean(axis=0)
        self._impl = None

    def build(self):
        """Build the acceleration structure (done lazily by the first query)."""
        if self._impl is not None:
            return self
        if self.engine == "open3d":
            from metrology.io._o3d import open3d

            o3d = open3d()
            scene = o3d.t.geometry.RaycastingScene()
            V = o3d.core.Tensor((np.asarray(self.mesh.vertices) - self._centre).astype(np.float32))
            F = o3d.core.Tensor(np.asarray(self.mesh.faces).astype(np.uint32))
            scene.add_triangles(V, F)
            self._impl = scene
        elif self.engine == "embree":
            from trimesh.ray.ray_pyembree import RayMeshIntersector

            self._impl = RayMeshIntersector(self.mesh)
        else:
            from trimesh.ray.ray_triangle import RayMeshIntersector

            self._impl = RayMeshIntersector(self.mesh)
            self.mesh.triangles_tree  # noqa: B018  (the r-tree, built now)
        # the engines build their BVH lazily at the first query: do it now, so that the
        # build is paid here and timings separate build and query
        c = self._centre
        self.first_triangle(c[None] + [0.0, 0.0, 1.0], np.array([[0.0, 0.0, -1.0]]))
        return self

    def first_triangle(self, origins, directions):
        """Index of the first triangle hit, ``(m,)`` int, -1 on a miss (engine precision)."""
        self.build()
        origins = np.asarray(origins, float).reshape(-1, 3)
        directions = np.asarray(directions, float).reshape(-1, 3)
        if len(origins) == 0:
            return np.zeros(0, dtype=np.int64)
        if self.engine == "open3d":
            from metrology.io._o3d import open3d

            o3d = open3d()
            rays = np.hstack([origins - self._centre, directions]).astype(np.float32)
            ans = self._impl.cast_rays(o3d.core.Tensor(rays))
            ids = ans["primitive_ids"].numpy().astype(np.int64)
            ids[ids == int(self._impl.INVALID_ID)] = -1
            return ids
        return np.asarray(self._impl.intersects_first(origins, directions), dtype=np.int64)

    def raw_distance(self, origins, directions):
        """Distance to the first hit as the engine computes it (float32 for Open3D), inf on a miss."""
        self.build()
        if self.engine != "open3d":
            return self.cast(origins, directions)[1]
        from metrology.io._o3d import open3d

        o3d = open3d()
        rays = np.hstack([np.asarray(origins, float) - self._centre, directions]).astype(np.float32)
        return self._impl.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(float)

    def cast(self, origins, directions):
        """First hits, refined in double precision.

        Parameters
        ----------
        origins : (m, 3) float, mm, panel frame
        directions : (m, 3) float, unit, panel frame

        Returns
        -------
        tri : (m,) int, face index, -1 on a miss
        t : (m,) float, mm, distance along the ray; NaN on a miss
        bary : (m, 3) float, barycentric coordinates of the hit; NaN on a miss
        """
        origins = np.asarray(origins, float).reshape(-1, 3)
        directions = np.asarray(directions, float).reshape(-1, 3)
        tri = self.first_triangle(origins, directions)
        t = np.full(len(tri), np.nan)
        bary = np.full((len(tri), 3), np.nan)
        hit = tri >= 0
        if np.any(hit):
            v0, v1, v2 = (self._tri[tri[hit], k] for k in range(3))
            e1, e2 = v1 - v0, v2 - v0
            d = directions[hit]
            pv = np.cross(d, e2)
            det = np.sum(e1 * pv, axis=1)
            tv = origins[hit] - v0
            u = np.sum(tv * pv, axis=1) / det
            qv = np.cross(tv, e1)
            v = np.sum(d * qv, axis=1) / det
            t[hit] = np.sum(e2 * qv, axis=1) / det
            bary[hit] = np.column_stack([1.0 - u - v, u, v])
        return tri, t, bary

    def closest(self, points):
        """Closest points on the mesh (Open3D finds the triangle, refined in double).

        Parameters
        ----------
        points : (m, 3) float, mm, panel frame

        Returns
        -------
        tri : (m,) int
        closest : (m, 3) float, mm, panel frame
        """
        import trimesh

        from metrology.io._o3d import open3d

        o3d = open3d()
        if self.engine == "open3d":
            self._closest_scene = self.build()._impl
        if not hasattr(self, "_closest_scene"):
            scene = o3d.t.geometry.RaycastingScene()
            scene.add_triangles(
                o3d.core.Tensor((np.asarray(self.mesh.vertices) - self._centre).astype(np.float32)),
                o3d.core.Tensor(np.asarray(self.mesh.faces).astype(np.uint32)),
            )
            self._closest_scene = scene
        points = np.asarray(points, float).reshape(-1, 3)
        ans = self._closest_scene.compute_closest_points(o3d.core.Tensor((points - self._centre).astype(np.float32)))
        tri = ans["primitive_ids"].numpy().astype(np.int64)
        return tri, trimesh.triangles.closest_point(self._tri[tri], points)


# --- drilling points ------------------------------------------------------------------


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


def panel_plane(mesh):
    """Area-weighted best-fit plane of a mesh.

    Returns
    -------
    centre : (3,) float, mm, panel frame
    basis : (3, 3) float, rows e1, e2, n (n: the side the faces' normals point to; e1 the
        projection of the panel-frame axis closest to the plane)
    """
    w = np.asarray(mesh.area_faces)
    c = np.asarray(mesh.triangles_center)
    centre = (w[:, None] * c).sum(0) / w.sum()
    Q = (c - centre) * np.sqrt(w)[:, None]
    vt = np.linalg.svd(Q, full_matrices=False)[2]
    n = vt[2] if np.dot(vt[2], (w[:, None] * mesh.face_normals).sum(0)) >= 0 else -vt[2]
    # e1: the panel-frame axis most in the plane, projected (CAD grids follow the axes;
    # the in-plane principal axes of a square panel are arbitrary)
    k = int(np.argmin(np.abs(n)))
    e1 = np.eye(3)[k] - n[k] * n
    e1 /= np.linalg.norm(e1)
    return centre, np.vstack([e1, np.cross(n, e1), n])


def grid_points(panel: Panel, spacing: float, caster: RayCaster) -> DrillPoints:
    """A regular grid of drilling points over the panel.

    The grid (step ``spacing`` mm) lies in the panel's best-fit plane; each node is
    projected onto the mesh along the plane normal; nodes whose projection misses the
    panel are dropped.
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
    labels = tuple(f"grid {a},{b}" for a, b in zip(iu.ravel()[hit], iv.ravel()[hit]))
    if not len(pts):
        raise ValueError(f"{panel.source}: no grid point of spacing {spacing} mm falls on the panel")
    return DrillPoints(pts, np.full_like(pts, np.nan), labels)


def snap_points(panel: Panel, caster: RayCaster, points):
    """Snap drilling points onto the mesh.

    Parameters
    ----------
    points : (m, 3) float, mm, panel frame

    Returns
    -------
    snapped : (m, 3) float, mm, panel frame, the closest points on the mesh
    distance : (m,) float, mm, how far each point was from the mesh
    normal : (m, 3) float, unit, panel frame, interpolated vertex normal, out of the panel
    """
    import trimesh

    tri, snapped = caster.closest(points)
    bary = trimesh.triangles.points_to_barycentric(np.asarray(panel.mesh.triangles)[tri], snapped)
    bary = np.clip(bary, 0.0, 1.0)
    bary /= bary.sum(1, keepdims=True)
    return snapped, np.linalg.norm(snapped - points, axis=1), panel.vertex_normal_at(tri, bary)


# --- the head ---------------------------------------------------------------------------


def tool_axis_tcs(layout: SensorLayout):
    """The tool (feed) axis of a layout in its TCS: ``+e_z`` or ``-e_z``, the side the beams point to.

    Returns
    -------
    a : (3,) float, unit, TCS
    """
    m = layout.direction.mean(axis=0)
    m = m / np.linalg.norm(m)
    if np.degrees(np.arccos(min(1.0, abs(m[2])))) > AXIS_MAX_DEG:
        raise ValueError(f"the layout's beams do not point along the TCS z axis (mean direction {np.round(m, 4).tolist()}); the tool axis must be +-z")
    return np.array([0.0, 0.0, math.copysign(1.0, m[2])])


def default_standoff(layout: SensorLayout) -> float:
    """A stand-off (mm) when none is given.

    The distance along the tool axis from the sensor-zero plane to the TCS origin when the
    origin lies ahead of that plane, between 20 % and 80 % of the way to where the beams
    cross the tool axis (the paper's Table 6: 35 mm, the pressure-foot datum); otherwise
    half the distance to the crossing (Table 2: 43.3 mm, spots at half the foot radius).
    """
    a = tool_axis_tcs(layout)
    z0 = float(np.mean(layout.zero @ a))
    # how far along the axis does each beam reach the axis? (lateral closing rate)
    r = np.linalg.norm(layout.zero[:, :2], axis=1)
    lat = -np.sum(layout.zero[:, :2] * layout.direction[:, :2], axis=1) / np.maximum(r, 1e-12)
    axial = layout.direction @ a
    ok = lat > 1e-6
    if not np.any(ok):
        raise ValueError("the beams do not converge towards the tool axis; give the stand-off explicitly")
    cross = float(np.mean(r[ok] / lat[ok] * axial[ok]))
    if 0.2 * cross <= -z0 <= 0.8 * cross:
        return -z0
    return 0.5 * cross


def _perp_basis(v):
    """Two unit vectors ``(m, 3)`` perpendicular to unit ``v (m, 3)`` and to each other."""
    helper = np.where(np.abs(v[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(v, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(v, e1)


def _rotvec_matrix(rv):
    """Rotation matrices ``(m, 3, 3)`` of rotation vectors ``(m, 3)`` (rad), Rodrigues."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(rv, float).reshape(-1, 3)).as_matrix()


def tilted_feed(normal, tilt, rng):
    """Feed directions: the inward normal tilted by ``tilt`` about a random azimuth.

    Parameters
    ----------
    normal : (m, 3) float, unit, panel frame, out of the panel
    tilt : float, rad
    rng : numpy.random.Generator

    Returns
    -------
    feed : (m, 3) float, unit, panel frame, into the panel
    """
    n = np.asarray(normal, float)
    e1, e2 = _perp_basis(n)
    az = rng.uniform(0.0, 2 * np.pi, len(n))
    w = np.cos(az)[:, None] * e1 + np.sin(az)[:, None] * e2
    return np.einsum("mij,mj->mi", _rotvec_matrix(w * tilt), -n)


def orientation_from_feed(feed, a_tcs):
    """tcs2panel rotations ``(m, 3, 3)`` that turn the TCS tool axis onto ``feed`` ``(m, 3)``.

    The roll about the axis is fixed so that the TCS x axis lies in the plane of the feed
    and the panel x axis (the panel y axis where the feed is along x).
    """
    f = np.asarray(feed, float)
    ref = np.where(np.abs(f[:, :1]) < 0.95, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    x = ref - np.sum(ref * f, axis=1, keepdims=True) * f
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    # columns: images of TCS x, y, z; TCS z goes to f * sign so that R a_tcs = f
    s = a_tcs[2]
    z = f * s
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def place_head(points, R, a_tcs, layout: SensorLayout, standoff):
    """TCS origins so that the tool axis meets ``points`` at ``standoff``.

    Parameters
    ----------
    points : (m, 3) float, mm, panel frame, drilling points
    R : (m, 3, 3) float, tcs2panel rotations
    a_tcs : (3,) float, unit, TCS tool axis
    layout : SensorLayout
    standoff : float, mm, from the sensor-zero plane to the drilling point along the axis

    Returns
    -------
    T : (m, 3) float, mm, panel frame
    """
    z0 = float(np.mean(layout.zero @ a_tcs))
    return np.asarray(points, float) - (R @ a_tcs) * (z0 + standoff)


def cast_beams(caster: RayCaster, layout: SensorLayout, R, T):
    """Cast the layout's beams from poses ``(R, T)``.

    Returns
    -------
    d : (m, n) float, mm, readings without noise; NaN where a beam missed or hit from behind
    tri : (m, n) int, face hit, -1 on a miss
    behind : (m, n) bool, the beam hit a face from behind
    """
    m, n = len(T), layout.n
    origins = (np.einsum("mij,nj->mni", R, layout.zero) + T[:, None, :]).reshape(-1, 3)
    dirs = np.einsum("mij,nj->mni", R, layout.direction).reshape(-1, 3)
    tri, t, _ = caster.cast(origins, dirs)
    behind = np.zeros(len(tri), bool)
    hit = tri >= 0
    v = caster._tri[tri[hit]]  # face normals of the hit faces only (not of the whole mesh)
    fn = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    behind[hit] = np.sum(fn * dirs[hit], axis=1) > 0
    t = np.where(behind | ~hit | (t < 0), np.nan, t)
    return t.reshape(m, n), tri.reshape(m, n), behind.reshape(m, n)


# --- the micro-sphere -------------------------------------------------------------------


def fit_algebraic_sphere(S, noise_mm=0.0, prior_radius_mm=SPHERE_PRIOR_RADIUS_MM):
    """The algebraic sphere ``A |x|^2 + b . x + c = 0`` through (or nearest) the spots, MAP.

    Points are centred and scaled by their RMS radius ``s``; the coefficient vector
    ``u = (A, b, c)`` minimises ``|M u|^2 + lambda A^2`` with ``|u| = 1`` (the smallest
    eigenvector). Near the spots ``|b| ~ 1``, a row of ``M u`` is the spot's height off the
    sphere over ``s`` and ``A = kappa s / 2``, so with ``lambda = 4 sigma^2 / (kappa0^2 s^4)``
    this is the maximum a posteriori sphere for reading noise ``sigma`` and a prior
    ``kappa ~ N(0, kappa0^2)``, ``kappa0 = 1 / prior_radius_mm``: a curvature is believed
    only as far as the spots' geometry resolves it above the noise. With well-spread spots
    and no noise four spots give the sphere through them; where the spots do not determine
    the curvature (coplanar and concyclic: flat panel, symmetric head) the flattest member
    of the pencil, the plane, is chosen. ``A -> 0`` is a plane: nothing divides by the
    radius, so nothing blows up.

    Parameters
    ----------
    S : (p, n, 3) float, mm, any frame, n >= 4, all finite
    noise_mm : float, mm, 1 sigma of a spot along the normal (floored at
        :data:`SPHERE_NOISE_FLOOR_MM`)
    prior_radius_mm : float, mm; inf: no prior (the exact interpolating sphere)

    Returns
    -------
    u : (p, 5) float, coefficients in scaled coordinates ``x' = (x - centre) / scale``
    centre : (p, 3) float, mm
    scale : (p,) float, mm
    """
    S = np.asarray(S, float)
    if S.ndim != 3 or S.shape[-1] != 3 or S.shape[1] < 4:
        raise ValueError(f"a sphere needs (p, n>=4, 3) points, got shape {S.shape}")
    centre = S.mean(axis=1)
    X = S - centre[:, None, :]
    scale = np.sqrt(np.mean(np.sum(X * X, axis=2), axis=1))
    scale = np.where(scale > 0, scale, 1.0)
    X = X / scale[:, None, None]
    M = np.concatenate([np.sum(X * X, axis=2, keepdims=True), X, np.ones(X.shape[:2] + (1,))], axis=2)
    sigma = max(float(noise_mm), SPHERE_NOISE_FLOOR_MM)
    kappa0 = 1.0 / float(prior_radius_mm)
    lam = 4.0 * sigma**2 / (kappa0**2 * scale**4) if kappa0 > 0 else np.zeros_like(scale)
    # the prior as one more row (SVD of the stacked matrix: no squared condition number);
    # a tiny floor breaks the tie of an exactly concyclic pencil towards the plane
    prior = np.zeros((len(S), 1, 5))
    prior[:, 0, 0] = np.sqrt(lam + 1e-24)
    _, _, vt = np.linalg.svd(np.concatenate([M, prior], axis=1), full_matrices=True)
    return vt[:, -1, :], centre, scale


def micro_sphere_normal(zero, direction, d, axis=(0.0, 0.0, 1.0), origin=(0.0, 0.0, 0.0), noise_mm=0.0,
                        prior_radius_mm=SPHERE_PRIOR_RADIUS_MM):
    """Micro-sphere normal at the point where the tool axis meets the sphere through the spots.

    Parameters
    ----------
    zero : (n, 3) float, mm, TCS
    direction : (n, 3) float, unit, TCS
    d : (p, n) float, mm, readings; a pose with a NaN reading gives NaN
    axis : (3,) float, unit, TCS, the tool axis direction
    origin : (3,) float, mm, TCS, a point of the tool axis
    noise_mm, prior_radius_mm : float, mm, see :func:`fit_algebraic_sphere`

    Returns
    -------
    n : (p, 3) float, unit, TCS, oriented against the mean beam direction
    radius : (p,) float, mm, the sphere's radius; inf where it degraded to the plane
    point : (p, 3) float, mm, TCS, where the axis meets the sphere (nearest to the axis
        where it misses)
    misses : (p,) bool, the axis misses the sphere (the normal is then taken at the point
        of the sphere nearest to the axis)

    Notes
    -----
    With 3 sensors a sphere through the spots is underdetermined: the micro-plane is
    returned (radius inf). With more than 4 sensors the sphere is the algebraic
    least-squares one.
    """
    zero = np.asarray(zero, float)
    direction = np.asarray(direction, float)
    S = projection_points(zero, direction, d)
    p = S.shape[0]
    toward = -direction.mean(axis=0)
    toward /= np.linalg.norm(toward)
    axis = np.asarray(axis, float)
    origin = np.asarray(origin, float)
    n_out = np.full((p, 3), np.nan)
    rad = np.full(p, np.nan)
    pt = np.full((p, 3), np.nan)
    miss = np.zeros(p, bool)
    ok = np.all(np.isfinite(S), axis=(1, 2))
    if S.shape[1] < 4:
        n_out[ok] = micro_plane_normal(zero, direction, np.atleast_2d(d)[ok], method="lsq")
        rad[ok] = np.inf
        # the plane's axis point: through the spot centroid
        c = S[ok].mean(axis=1)
        t = np.sum((c - origin) * n_out[ok], axis=1) / (n_out[ok] @ axis)
        pt[ok] = origin + t[:, None] * axis
        return n_out, rad, pt, miss
    if not np.any(ok):
        return n_out, rad, pt, miss
    u, c, s = fit_algebraic_sphere(S[ok], noise_mm, prior_radius_mm)
    A, b, c0 = u[:, 0], u[:, 1:4], u[:, 4]
    X0 = (origin - c) / s[:, None]  # axis origin, scaled coordinates
    # A t^2 + B t + C = 0 along X0 + t a
    B = 2 * A * (X0 @ axis) + b @ axis
    C = A * np.sum(X0 * X0, axis=1) + np.sum(b * X0, axis=1) + c0
    disc = B * B - 4 * A * C
    m = disc < 0
    disc = np.where(m, 0.0, disc)
    q = -0.5 * (B + np.copysign(np.sqrt(disc), B))
    flat = np.abs(A) < SPHERE_FLAT_A
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane_like = np.where(q != 0, C / q, -C / np.where(B != 0, B, 1.0))
        t_other = np.where(flat, np.nan, q / np.where(flat, 1.0, A))
        t_tangent = -B / (2 * np.where(flat, 1.0, A))
    # of the two roots, the one nearer to the spots' centroid projected on the axis: it is
    # the one that tends to the plane's root as A -> 0 (and on a tie, that one). For a
    # sphere the size of the spot circle the two are equally near and equally wrong: such a
    # sphere is a model error (a cylinder or saddle under four spots; see the study)
    tc = np.sum(-X0 * axis, axis=1)  # axis parameter nearest the spot centroid (origin 0)
    pick_other = ~flat & (np.abs(t_other - tc) < np.abs(t_plane_like - tc) - 1e-12)
    t = np.where(pick_other, t_other, t_plane_like)
    t = np.where(m & ~flat, t_tangent, t)
    X = X0 + t[:, None] * axis
    g = 2 * A[:, None] * X + b
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    g *= np.where(np.sum(g * toward, axis=1) < 0, -1.0, 1.0)[:, None]
    n_out[ok] = g
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = np.sum(b * b, axis=1) - 4 * A * c0
        rad[ok] = np.where(flat, np.inf, np.sqrt(np.maximum(r2, 0.0)) / (2 * np.abs(A)) * s)
    pt[ok] = c + X * s[:, None]
    miss[ok] = m & ~flat
    return n_out, rad, pt, miss


# --- measuring at poses and the attitude loop -------------------------------------------


@dataclass(frozen=True)
class MotionError:
    """The robot's error in executing an attitude adjustment.

    The executed rotation vector is ``(1 + scale g) w + repeat h`` for a commanded ``w``
    (``g ~ N(0, 1)``, ``h ~ N(0, I3)``), and the tool centre point lands
    ``position_mm N(0, I3)`` off (then back on the surface along the tool axis).

    Attributes
    ----------
    repeat : float, rad, 1 sigma per axis
    scale : float, unitless, 1 sigma relative error of the commanded rotation
    position_mm : float, mm, 1 sigma per axis
    """

    repeat: float = math.radians(0.02)
    scale: float = 0.03
    position_mm: float = 0.05

    def __post_init__(self):
        for k in ("repeat", "scale", "position_mm"):
            v = getattr(self, k)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"motion error {k} must be a finite number >= 0, got {v}")


def _readings(caster, layout_true, R, T, noise, rng):
    """Noisy readings from poses ``(R, T)``.

    Returns
    -------
    d : (m, n) float, mm, with noise; NaN for every sensor of a pose with a bad beam
    miss, behind, out_of_range : (m, n) bool, per beam (a beam is counted in one only)
    """
    d, tri, behind = cast_beams(caster, layout_true, R, T)
    miss = tri < 0
    beh = behind & ~miss
    d = d + rng.standard_normal(d.shape) * noise
    lo, hi = layout_true.range_mm[:, 0], layout_true.range_mm[:, 1]
    oor = ((d < lo) | (d > hi)) & ~miss & ~beh
    bad = np.any(miss | beh | oor, axis=1)
    return np.where(bad[:, None], np.nan, d), miss, beh, oor


def _beam_detail(names, miss, beh, oor):
    """Per pose, which beams failed and why (``"L3 missed; L4 out of range"``), '' if none."""
    out = []
    for i in range(len(miss)):
        parts = []
        for mask, what in ((miss[i], "missed"), (beh[i], "hit from behind"), (oor[i], "out of range")):
            if np.any(mask):
                parts.append(" ".join(n for n, b in zip(names, mask) if b) + " " + what)
        out.append("; ".join(parts))
    return out


def _normal_from(layout_est, a_tcs, R, d, method, noise_mm=0.0, prior_radius_mm=SPHERE_PRIOR_RADIUS_MM):
    """Normal by ``method`` ("plane" or "sphere") from readings ``d (m, n)``.

    Returns
    -------
    n : (m, 3) float, unit, panel frame, out of the panel; NaN where d has NaN
    radius : (m,) float, mm (inf for the plane)
    """
    if method == "plane":
        n_tcs = micro_plane_normal(layout_est.zero, layout_est.direction, d)
        rad = np.full(len(d), np.inf)
    elif method == "sphere":
        n_tcs, rad, _, _ = micro_sphere_normal(layout_est.zero, layout_est.direction, d, axis=a_tcs,
                                               noise_mm=noise_mm, prior_radius_mm=prior_radius_mm)
    else:
        raise ValueError(f"method must be 'plane' or 'sphere', got {method!r}")
    return np.einsum("mij,mj->mi", R, n_tcs), rad


def _axis_surface(caster, panel, P_axis, f):
    """Where the tool axis through ``P_axis`` along ``f`` meets the panel, and the normal there."""
    tri, t, bary = caster.cast(P_axis - 50.0 * f, f)
    hit = tri >= 0
    pts = np.where(hit[:, None], P_axis - 50.0 * f + np.nan_to_num(t)[:, None] * f, P_axis)
    nrm = np.full_like(pts, np.nan)
    if np.any(hit):
        nrm[hit] = panel.vertex_normal_at(tri[hit], bary[hit])
    if panel.surface is not None:
        nrm = np.where(hit[:, None], panel.surface.normal(pts), nrm)
    return pts, nrm, hit


def _feed_frame(a_tcs):
    """``F`` (3, 3): TCS to a frame whose +z is the tool axis (identity or Rot(X, pi))."""
    return np.eye(3) if a_tcs[2] > 0 else np.diag([1.0, -1.0, -1.0])


def attitude_loop(caster, panel, layout_true, layout_est, points, R0, standoff, noise, rng, method,
                  tolerance, motion: MotionError, max_adjustments=MAX_ADJUSTMENTS,
                  prior_radius_mm=SPHERE_PRIOR_RADIUS_MM):
    """The attitude loop of section 4.2 (Eqs. 20-22) at many points at once.

    At each step the head measures the normal (``method``: "plane" or "sphere"); if the
    measured deviation between the tool axis and the normal is under ``tolerance`` the point
    is done; otherwise the robot turns the TCS by ``Rot(Y, theta) Rot(X, phi)`` of Eq. 22
    (in a frame whose +z is the tool axis), with ``motion`` errors, pivoting about the
    drilling point, and measures again.

    Parameters
    ----------
    points : (m, 3) float, mm, panel frame
    R0 : (m, 3, 3) float, initial tcs2panel rotations
    standoff : float, mm
    noise : (n,) float, mm, reading noise 1 sigma
    tolerance : float, rad
    rng : numpy.random.Generator

    Returns
    -------
    dict of arrays (m,): ``iterations`` (adjustments made), ``converged`` (bool),
    ``measured_dev`` (rad, last measured), ``final_dev`` (rad, true deviation of the final
    tool axis from the true normal where it meets the panel), ``theta``, ``phi`` (rad, the
    first adjustment; 0 where none was needed), ``lost`` (a beam missed during the loop)
    """
    a_tcs = tool_axis_tcs(layout_est)
    F = _feed_frame(a_tcs)
    m = len(points)
    R = np.array(R0, float)
    P = np.array(points, float)
    it = np.zeros(m, int)
    done = np.zeros(m, bool)
    lost = np.zeros(m, bool)
    mdev = np.full(m, np.nan)
    theta0 = np.zeros(m)
    phi0 = np.zeros(m)
    for k in range(max_adjustments + 1):
        act = ~done & ~lost
        if not np.any(act):
            break
        Ra, Pa = R[act], P[act]
        T = place_head(Pa, Ra, a_tcs, layout_est, standoff)
        d, _, _, _ = _readings(caster, layout_true, Ra, T, noise, rng)
        n_meas, _ = _normal_from(layout_est, a_tcs, Ra, d, method, float(np.mean(noise)), prior_radius_mm)
        bad = ~np.all(np.isfinite(n_meas), axis=1)
        f = Ra @ a_tcs
        dev = angle_between(f, -np.nan_to_num(n_meas), oriented=True)
        idx = np.flatnonzero(act)
        lost[idx[bad]] = True
        mdev[idx[~bad]] = dev[~bad]
        ok_now = ~bad & (dev < tolerance)
        done[idx[ok_now]] = True
        go = ~bad & ~ok_now
        if k == max_adjustments or not np.any(go):
            break
        # Eq. 22 in the feed frame: the inward measured normal, expressed there
        n_in_tcs = np.einsum("mji,mj->mi", Ra[go], -n_meas[go])
        n_feed = n_in_tcs @ F.T
        theta, phi = attitude_angles(n_feed)
        first = it[idx[go]] == 0
        theta0[idx[go][first]] = theta[first]
        phi0[idx[go][first]] = phi[first]
        adj = np.stack([F.T @ rot_y(th) @ rot_x(ph) @ F for th, ph in zip(theta, phi)])
        from scipy.spatial.transform import Rotation

        w = Rotation.from_matrix(adj).as_rotvec()  # commanded, TCS
        g = rng.standard_normal(len(w))
        h = rng.standard_normal(w.shape)
        w_exec = (1 + motion.scale * g)[:, None] * w + motion.repeat * h
        Rn = Ra[go] @ _rotvec_matrix(w_exec)
        # the TCP pivots about the drilling point, lands a little off, back onto the panel
        fn = Rn @ a_tcs
        Pn = Pa[go] + motion.position_mm * rng.standard_normal((int(go.sum()), 3))
        Pn, _, hit = _axis_surface(caster, panel, Pn, fn)
        lost[idx[go][~hit]] = True
        R[idx[go]] = Rn
        P[idx[go]] = Pn
        it[idx[go]] += 1
    f = R @ a_tcs
    _, n_true, hit = _axis_surface(caster, panel, P, f)
    final = angle_between(f, -np.nan_to_num(n_true), oriented=True)
    final[~hit] = np.nan
    return {"iterations": it, "converged": done, "measured_dev": mdev, "final_dev": final,
            "theta": theta0, "phi": phi0, "lost": lost | ~hit}


@dataclass
class NormalsRun:
    """Per-point results of :func:`run_normals`; arrays of length m unless stated.

    Attributes
    ----------
    labels : tuple of str
    points : (m, 3) float, mm, panel frame, drilling points on the panel
    status : (m,) str, a key of :data:`STATUS`
    off_mm : (m,) float, mm, distance of the given point from the panel
    n_true : (m, 3) float, unit, panel frame, interpolated vertex normal, out
    n_analytic : (m, 3) float or None, unit, panel frame, for generated panels
    n_plane, n_sphere : (m, 3) float, unit, panel frame, out; NaN unless status ok
    err_plane, err_sphere : (m,) float, rad, angle to the reference normal (:attr:`n_ref`)
    sphere_radius : (m,) float, mm, inf where the sphere degraded to the plane
    readings : (m, n) float, mm
    initial_tilt : (m,) float, rad, true deviation of the initial tool axis
    loop : dict method -> dict of arrays (see :func:`attitude_loop`), or empty
    engine : str; info : dict of run settings
    detail : (m,) str, why a point was not measured (which beams, how far off), '' if ok
    """

    labels: tuple
    points: np.ndarray
    status: np.ndarray
    off_mm: np.ndarray
    n_true: np.ndarray
    n_analytic: np.ndarray | None
    n_plane: np.ndarray
    n_sphere: np.ndarray
    err_plane: np.ndarray
    err_sphere: np.ndarray
    sphere_radius: np.ndarray
    readings: np.ndarray
    initial_tilt: np.ndarray
    loop: dict
    engine: str
    info: dict
    detail: np.ndarray

    @property
    def n_ref(self):
        """The reference normal: analytic where known, else the interpolated vertex normal."""
        return self.n_analytic if self.n_analytic is not None else self.n_true


def run_normals(panel: Panel, layout: SensorLayout, drill: DrillPoints, rng, *, tilt=math.radians(1.0),
                standoff=None, noise=None, tolerance=math.radians(0.5), engine="auto",
                motion: MotionError = MotionError(), layout_true: SensorLayout | None = None,
                loop=True, caster: RayCaster | None = None,
                prior_radius_mm=SPHERE_PRIOR_RADIUS_MM) -> NormalsRun:
    """Measure the normal at each drilling point by both methods, and run the attitude loop.

    Parameters
    ----------
    panel : Panel
    layout : SensorLayout, used to compute the normals (nominal or calibrated)
    drill : DrillPoints
    rng : numpy.random.Generator, the only source of randomness
    tilt : float, rad, attitude error of the initial tool axis (random azimuth)
    standoff : float, mm, or None for :func:`default_standoff`
    noise : (n,) or scalar float, mm, reading noise 1 sigma; None: the layout's ``noise_mm``
        (0 where not stated)
    tolerance : float, rad, of the attitude loop
    engine : {"auto", "trimesh", "embree", "open3d"}
    motion : MotionError
    layout_true : SensorLayout, the head as it really is (default ``layout``)
    loop : bool, run the attitude loop
    caster : RayCaster, to reuse a built scene (its mesh must be ``panel.mesh``)
    prior_radius_mm : float, mm, the micro-sphere's curvature prior (see
        :func:`fit_algebraic_sphere`); inf for the exact interpolating sphere

    Returns
    -------
    NormalsRun
    """
    layout_true = layout if layout_true is None else layout_true
    if layout_true.n != layout.n:
        raise ValueError(f"true and estimating layouts differ in sensor count ({layout_true.n} vs {layout.n})")
    if layout.n < 3:
        raise ValueError(f"a layout needs at least 3 sensors, got {layout.n}")
    if not (0 <= tilt < MAX_TILT):
        raise ValueError(f"tilt must be in [0, {math.degrees(MAX_TILT):g}) deg, got {math.degrees(tilt):g} deg")
    if not (tolerance > 0 and math.isfinite(tolerance)):
        raise ValueError(f"tolerance must be a positive angle, got {tolerance}")
    if not prior_radius_mm > 0:
        raise ValueError(f"the micro-sphere's prior radius must be > 0 mm (inf: no prior), got {prior_radius_mm}")
    a_tcs = tool_axis_tcs(layout)
    if not np.array_equal(tool_axis_tcs(layout_true), a_tcs):
        raise ValueError(f"the true layout's beams point {tool_axis_tcs(layout_true)[2]:+.0f}z, the layout's "
                         f"{a_tcs[2]:+.0f}z: they are not the same head")
    standoff = default_standoff(layout) if standoff is None else float(standoff)
    if not (math.isfinite(standoff) and standoff > 0):
        raise ValueError(f"stand-off must be a positive number of mm, got {standoff}")
    if noise is None:
        noise = np.nan_to_num(layout_true.noise_mm, nan=0.0)
    noise = np.broadcast_to(np.asarray(noise, float), (layout.n,)).copy()
    if np.any(~np.isfinite(noise)) or np.any(noise < 0):
        raise ValueError(f"reading noise must be finite and >= 0 mm, got {noise.tolist()}")
    caster = RayCaster(panel.mesh, engine) if caster is None else caster
    m = len(drill.points)
    pts, off, n_true = snap_points(panel, caster, drill.points)
    status = np.full(m, "ok", dtype=object)
    status[off > ON_PANEL_MM] = "off_panel"
    has_app = np.all(np.isfinite(drill.approach), axis=1)
    behind_app = has_app & (np.sum(drill.approach * n_true, axis=1) >= 0)
    status[(status == "ok") & behind_app] = "approach_behind"
    n_an = panel.surface.normal(pts) if panel.surface is not None else None
    n_ref = n_an if n_an is not None else n_true
    # initial feed: the approach direction where given, else the inward normal; tilted
    base = np.where(has_app[:, None], -drill.approach, n_ref)
    feed = tilted_feed(base, tilt, rng)
    R0 = orientation_from_feed(feed, a_tcs)
    T0 = place_head(pts, R0, a_tcs, layout, standoff)
    rng_read, rng_loop_p, rng_loop_s = rng.spawn(3)
    # both methods see the same noisy readings at the first pose
    d, miss_b, beh_b, oor_b = _readings(caster, layout_true, R0, T0, noise, rng_read)
    miss, beh, oor = np.any(miss_b, axis=1), np.any(beh_b, axis=1), np.any(oor_b, axis=1)
    n_plane, _ = _normal_from(layout, a_tcs, R0, d, "plane")
    n_sphere, rad = _normal_from(layout, a_tcs, R0, d, "sphere", float(np.mean(noise)), prior_radius_mm)
    for flag, name in ((oor, "out_of_range"), (beh, "beam_behind"), (miss, "beam_miss")):
        status[(status == "ok") & flag] = name
    good = status == "ok"
    detail = np.array(_beam_detail(layout_true.names, miss_b, beh_b, oor_b), dtype=object)
    detail[status == "off_panel"] = np.char.mod("%.3f mm from the panel", off[status == "off_panel"]).astype(object)
    detail[status == "approach_behind"] = "approach direction points out of the panel"
    detail[good] = ""
    n_plane[~good] = np.nan
    n_sphere[~good] = np.nan
    rad[~good] = np.nan
    err_p = np.where(good, angle_between(n_plane, n_ref, oriented=True), np.nan)
    err_s = np.where(good, angle_between(n_sphere, n_ref, oriented=True), np.nan)
    init_tilt = angle_between(R0 @ a_tcs, -n_ref, oriented=True)
    loops = {}
    if loop and np.any(good):
        for method, r in (("plane", rng_loop_p), ("sphere", rng_loop_s)):
            res = attitude_loop(caster, panel, layout_true, layout, pts[good], R0[good], standoff, noise, r,
                                method, tolerance, motion, prior_radius_mm=prior_radius_mm)
            full = {}
            for k, v in res.items():
                arr = np.full(m, np.nan) if v.dtype.kind == "f" else np.zeros(m, v.dtype)
                if v.dtype.kind == "i":
                    arr = np.full(m, -1, int)
                arr[good] = v
                full[k] = arr
            loops[method] = full
    info = {"engine": caster.engine, "standoff_mm": standoff, "tilt_deg": math.degrees(tilt),
            "noise_mm": noise.tolist(), "tolerance_deg": math.degrees(tolerance),
            "motion": {"repeat_deg": math.degrees(motion.repeat), "scale": motion.scale, "position_mm": motion.position_mm},
            "tool_axis_tcs": a_tcs.tolist(), "reference_normal": "analytic" if n_an is not None else "interpolated vertex normals",
            "sensors": layout.n, "sphere_prior_radius_mm": prior_radius_mm}
    return NormalsRun(drill.labels, pts, status.astype(str), off, n_true, n_an, n_plane, n_sphere, err_p, err_s,
                      rad, d, init_tilt, loops, caster.engine, info, detail.astype(str))


def _stats(err):
    e = np.degrees(err[np.isfinite(err)])
    if not len(e):
        return {"n": 0, "max_deg": math.nan, "mean_deg": math.nan, "std_deg": math.nan, "p95_deg": math.nan}
    return {"n": int(len(e)), "max_deg": float(e.max()), "mean_deg": float(e.mean()),
            "std_deg": float(e.std(ddof=1)) if len(e) > 1 else 0.0, "p95_deg": float(np.percentile(e, 95))}


def summarize(run: NormalsRun) -> dict:
    """Summary per method, point status counts, and a recommendation.

    Returns
    -------
    dict with ``plane`` and ``sphere`` (``n``, ``max_deg``, ``mean_deg``, ``std_deg``,
    ``p95_deg``, ``within_tolerance``, and the loop's ``iterations_mean``,
    ``iterations_max``, ``converged``, ``final_max_deg``, ``final_mean_deg``),
    ``status`` (counts), ``recommendation`` (``method`` and ``text``), ``info``, and for
    generated panels ``mesh_vs_analytic_max_deg`` (interpolated vertex normals against the
    analytic normal: the tessellation error).
    """
    tol = math.radians(run.info["tolerance_deg"])
    out = {}
    for name, err in (("plane", run.err_plane), ("sphere", run.err_sphere)):
        s = _stats(err)
        fin = np.isfinite(err)
        s["within_tolerance"] = float(np.mean(err[fin] < tol)) if np.any(fin) else math.nan
        lp = run.loop.get(name)
        if lp is not None:
            sel = run.status == "ok"
            it = lp["iterations"][sel]
            fd = lp["final_dev"][sel]
            s.update({"iterations_mean": float(it.mean()), "iterations_max": int(it.max()),
                      "converged": float(lp["converged"][sel].mean()),
                      "lost": int(lp["lost"][sel].sum()),
                      "final_max_deg": float(np.degrees(np.nanmax(fd))) if np.any(np.isfinite(fd)) else math.nan,
                      "final_mean_deg": float(np.degrees(np.nanmean(fd))) if np.any(np.isfinite(fd)) else math.nan})
        out[name] = s
    if run.n_analytic is not None:
        sel = run.status == "ok"
        dev = angle_between(run.n_true[sel], run.n_analytic[sel], oriented=True)
        out["mesh_vs_analytic_max_deg"] = float(np.degrees(dev.max())) if len(dev) else math.nan
    counts = {k: int(np.sum(run.status == k)) for k in STATUS}
    out["status"] = counts
    out["recommendation"] = _recommend(run, out, tol)
    out["info"] = run.info
    return out


def _recommend(run, summ, tol):
    ok = np.isfinite(run.err_plane) & np.isfinite(run.err_sphere)
    if not np.any(ok):
        return {"method": None, "text": "no drilling point could be measured"}
    ep, es = np.degrees(run.err_plane[ok]), np.degrees(run.err_sphere[ok])
    sp, ss = summ["plane"], summ["sphere"]
    # decide on the worst case first (a hole out of tolerance is scrap), then the mean
    score_p = (sp["p95_deg"], sp["mean_deg"])
    score_s = (ss["p95_deg"], ss["mean_deg"])
    method = "plane" if score_p <= score_s else "sphere"
    other = "sphere" if method == "plane" else "plane"
    e_best, e_other = (ep, es) if method == "plane" else (es, ep)
    wins = e_other < e_best - 1e-6
    n_w = int(wins.sum())
    text = (f"micro-{method}: 95th percentile {summ[method]['p95_deg']:.4f} deg, mean {summ[method]['mean_deg']:.4f} deg "
            f"against micro-{other}'s {summ[other]['p95_deg']:.4f} / {summ[other]['mean_deg']:.4f} deg")
    if n_w:
        pts = run.points[ok][wins]
        gain = float(np.median(e_best[wins] - e_other[wins]))
        text += (f"; micro-{other} is better at {n_w} of {int(ok.sum())} points (median gain {gain:.4f} deg, "
                 f"x {pts[:, 0].min():.0f}..{pts[:, 0].max():.0f}, y {pts[:, 1].min():.0f}..{pts[:, 1].max():.0f}, "
                 f"z {pts[:, 2].min():.0f}..{pts[:, 2].max():.0f} mm)")
    else:
        text += f"; micro-{other} is not better at any point"
    frac = summ[method]["within_tolerance"]
    text += f"; {100 * frac:.1f} % of first measurements within {math.degrees(tol):g} deg"
    return {"method": method, "text": text, "other_wins": n_w}


def per_point_rows(run: NormalsRun) -> list:
    """Per-point records (plain dicts; degrees at this edge) for CSV/JSON output."""
    rows = []
    for i, label in enumerate(run.labels):
        r = {"label": label, "status": run.status[i], "detail": run.detail[i],
             "x": run.points[i, 0], "y": run.points[i, 1], "z": run.points[i, 2],
             "off_mm": run.off_mm[i], "initial_tilt_deg": math.degrees(run.initial_tilt[i])}
        nm = run.n_true[i]
        r.update({"n_mesh_x": nm[0], "n_mesh_y": nm[1], "n_mesh_z": nm[2]})
        if run.n_analytic is not None:
            na = run.n_analytic[i]
            r.update({"n_analytic_x": na[0], "n_analytic_y": na[1], "n_analytic_z": na[2]})
        for name, n, e in (("plane", run.n_plane, run.err_plane), ("sphere", run.n_sphere, run.err_sphere)):
            r.update({f"{name}_nx": n[i, 0], f"{name}_ny": n[i, 1], f"{name}_nz": n[i, 2], f"{name}_err_deg": math.degrees(e[i])})
        r["sphere_radius_mm"] = run.sphere_radius[i]
        for name in ("plane", "sphere"):
            lp = run.loop.get(name)
            if lp is not None:
                r.update({f"{name}_theta_deg": math.degrees(lp["theta"][i]), f"{name}_phi_deg": math.degrees(lp["phi"][i]),
                          f"{name}_iterations": int(lp["iterations"][i]), f"{name}_converged": bool(lp["converged"][i]),
                          f"{name}_final_dev_deg": math.degrees(lp["final_dev"][i])})
        rows.append(r)
    return rows


# --- output ------------------------------------------------------------------------------


def per_point_text(run: NormalsRun, fmt: str) -> str:
    """The per-point table as CSV (``fmt="csv"``) or JSON (``fmt="json"``) text."""
    import io
    import json

    rows = per_point_rows(run)

    def clean(v):
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        if isinstance(v, (float, np.floating)):
            return float(v) if math.isfinite(v) else None
        if isinstance(v, (np.integer,)):
            return int(v)
        return v

    if fmt == "json":
        return json.dumps([{k: clean(v) for k, v in r.items()} for r in rows], indent=1) + "\n"
    keys = list(rows[0].keys()) if rows else []
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(keys)
    for r in rows:
        out = []
        for k in keys:
            v = clean(r.get(k))
            out.append("" if v is None else (f"{v:.9g}" if isinstance(v, float) else v))
        w.writerow(out)
    return buf.getvalue()


def plot_error_map(run: NormalsRun, tolerance_deg: float) -> bytes:
    """A PNG map of both methods' errors over the panel (its best-fit plane), as bytes."""
    import io

    from metrology.report.plots import pyplot

    plt = pyplot()

    pts = run.points
    c = pts.mean(axis=0)
    n = np.linalg.svd(pts - c, full_matrices=False)[2][-1] if len(pts) >= 3 else np.array([0.0, 0.0, 1.0])
    n = n if np.all(np.isfinite(n)) and np.linalg.norm(n) > 0.5 else np.array([0.0, 0.0, 1.0])
    k = int(np.argmin(np.abs(n)))  # as in panel_plane: e1 from the panel-frame axis
    e1 = np.eye(3)[k] - n[k] * n
    e1 /= np.linalg.norm(e1)
    uv = (pts - c) @ np.vstack([e1, np.cross(n, e1)]).T
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), constrained_layout=True)
    ep, es = np.degrees(run.err_plane), np.degrees(run.err_sphere)
    vmax = float(np.nanmax(np.concatenate([ep, es, [tolerance_deg]])))
    for ax, e, name in ((axes[0], ep, "micro-plane"), (axes[1], es, "micro-sphere")):
        ok = np.isfinite(e)
        sc = ax.scatter(uv[ok, 0], uv[ok, 1], c=e[ok], cmap="viridis", vmin=0, vmax=vmax, s=18)
        if np.any(~ok):
            ax.scatter(uv[~ok, 0], uv[~ok, 1], marker="x", c="red", s=18, label="not measured")
            ax.legend(loc="upper right", fontsize=8)
        big = ok & (e > tolerance_deg)
        ax.scatter(uv[big, 0], uv[big, 1], facecolors="none", edgecolors="red", s=40)
        fin = e[ok]
        stats = f"max {fin.max():.3f}, mean {fin.mean():.3f} deg" if len(fin) else "no point"
        ax.set_title(f"{name}: {stats}")
        ax.set_xlabel("u (mm, panel best-fit plane)")
        ax.set_ylabel("v (mm)")
        ax.set_aspect("equal")
    fig.colorbar(sc, ax=axes, label=f"normal error (deg); red circles > {tolerance_deg:g} deg")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def normals_job(panel_path, layout_path, *, points_path=None, grid_mm=None, tilt_deg=1.0, standoff_mm=None,
                noise_mm=None, seed=0, tolerance_deg=0.5, engine="auto", out_path=None, plot_path=None,
                true_layout_path=None, motion_repeat_deg=0.02, motion_scale=0.03, motion_position_mm=0.05,
                prior_radius_mm=SPHERE_PRIOR_RADIUS_MM, loop=True) -> dict:
    """Everything ``metro normals`` does: load, measure, summarise, write (all or nothing).

    Degrees appear only here, at the edge. Output files are written only after every
    point has been computed (each atomically); a fatal error writes nothing.

    Returns
    -------
    dict: the :func:`summarize` summary plus ``warnings`` (list of str) and ``points``
    (how many given)
    """
    from metrology.core.layout import load_layout

    if (points_path is None) == (grid_mm is None):
        raise ValueError("give exactly one of --points FILE or --grid SPACING_MM")
    for name, v in (("tilt", tilt_deg), ("tolerance", tolerance_deg), ("motion repeat", motion_repeat_deg)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite angle >= 0 deg, got {v}")
    out_fmt = None
    if out_path is not None:
        out_fmt = str(out_path).lower().rsplit(".", 1)[-1]
        if out_fmt not in ("csv", "json"):
            raise ValueError(f"{out_path}: the per-point output must end in .csv or .json")
    if plot_path is not None and not str(plot_path).lower().endswith(".png"):
        raise ValueError(f"{plot_path}: the plot must be a .png file")
    layout = load_layout(layout_path)
    layout_true = load_layout(true_layout_path) if true_layout_path is not None else None
    panel = load_panel(panel_path)
    caster = RayCaster(panel.mesh, engine)
    drill = read_points(points_path) if points_path is not None else grid_points(panel, float(grid_mm), caster)
    rng = np.random.default_rng(seed)
    motion = MotionError(math.radians(motion_repeat_deg), motion_scale, motion_position_mm)
    run = run_normals(panel, layout, drill, rng, tilt=math.radians(tilt_deg), standoff=standoff_mm, noise=noise_mm,
                      tolerance=math.radians(tolerance_deg), motion=motion, layout_true=layout_true, loop=loop,
                      caster=caster, prior_radius_mm=prior_radius_mm)
    if not np.any(run.status == "ok"):
        counts = ", ".join(f"{int(np.sum(run.status == k))} {STATUS[k]}" for k in STATUS if k != "ok" and np.any(run.status == k))
        where = points_path if points_path is not None else f"grid {grid_mm} mm"
        raise ValueError(f"{where}: no drilling point could be measured ({counts})")
    summary = summarize(run)
    summary["warnings"] = list(panel.warnings)
    summary["points"] = len(run.labels)
    text = per_point_text(run, out_fmt) if out_fmt else None
    png = plot_error_map(run, tolerance_deg) if plot_path is not None else None
    from metrology.io.atomic import atomic_path, write_text

    if text is not None:
        write_text(out_path, text)
    if png is not None:
        with atomic_path(plot_path) as tmp:
            tmp.write_bytes(png)
    return summary


def summary_text(summary: dict) -> str:
    """The human summary table of :func:`normals_job`."""
    lines = [f"{'method':<8} {'n':>5} {'max_deg':>9} {'mean_deg':>9} {'std_deg':>9} {'p95_deg':>9} {'in_tol':>7} {'iter':>5} {'final_max':>9}"]
    for name in ("plane", "sphere"):
        s = summary[name]
        lines.append(f"{name:<8} {s['n']:>5d} {s['max_deg']:>9.4f} {s['mean_deg']:>9.4f} {s['std_deg']:>9.4f} {s['p95_deg']:>9.4f} "
                     f"{100 * s['within_tolerance']:>6.1f}% {s.get('iterations_mean', math.nan):>5.2f} {s.get('final_max_deg', math.nan):>9.4f}")
    bad = {k: v for k, v in summary["status"].items() if k != "ok" and v}
    if bad:
        lines.append("not measured: " + ", ".join(f"{v} {STATUS[k]}" for k, v in bad.items()))
    info = summary["info"]
    lines.append(f"engine {info['engine']}, stand-off {info['standoff_mm']:.3f} mm, tilt {info['tilt_deg']:g} deg, "
                 f"reference normal: {info['reference_normal']}")
    lines.append("recommendation: " + summary["recommendation"]["text"])
    return "\n".join(lines)

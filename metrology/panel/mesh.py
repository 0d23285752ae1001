"""A CAD panel: the mesh (STL, OBJ, PLY, GLB, STEP through cascadio), its analytic surface when known, and its plane."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
import numpy as np
from metrology.panel.surfaces import ParametricSurface


#: a drilling point farther than this from the mesh is "off the panel" (mm)
ON_PANEL_MM = 1.0


#: bounding-box diagonal outside this interval: warn "is the panel in mm?" (mm)
PLAUSIBLE_DIAGONAL_MM = (20.0, 50_000.0)


#: length units a panel file may be in: mm per unit (``--units``)
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}


#: trimesh's unit names (``mesh.units``, set by loaders that read units) to ours
_TRIMESH_UNITS = {"millimeters": "mm", "millimeter": "mm", "mm": "mm", "centimeters": "cm", "cm": "cm",
                  "meters": "m", "meter": "m", "m": "m", "inches": "in", "inch": "in", "in": "in"}


#: STEP tessellation (OpenCASCADE through cascadio): chord tolerance (mm) and angular
#: deflection (rad); 1 um chords keep the tessellation error far under reading noise
STEP_TOL_LINEAR_MM = 1e-3


STEP_TOL_ANGULAR_RAD = 5e-3


#: the reference normal of a mesh is smoothed only over faces whose normals make less than
#: this angle with the face hit (deg); as CAD tools' smoothing groups / auto-smooth: an
#: edge sharper than this is a designed crease, one gentler is tessellation of a curve
CREASE_ANGLE_DEG = 30.0


#: a face is not smoothed with a neighbour whose planar region (faces joined where they meet
#: at less than :data:`metrology.panel.edges.FLAT_RAD`) is this many times smaller in area:
#: a machined plane that meets a tangent fillet keeps its own normal up to the fillet; the
#: facets of a tessellated curve are alike and are smoothed together
TANGENT_AREA_RATIO = 16.0


@dataclass
class Panel:
    """A loaded, validated panel mesh.

    Attributes
    ----------
    mesh : trimesh.Trimesh, mm, panel frame; faces consistently wound, normals out
    source : str, where it came from (for messages)
    warnings : list of str, things repaired or suspicious (printed by the CLI)
    units : str, where the unit came from (``"mm (assumed: STL carries no units)"``)
    unit_warning : str or None, the one of ``warnings`` that doubts the unit (an implausible
        size), repeated by an error that may follow it
    surface : ParametricSurface or BRepSurface or None, the exact surface: analytic when the
        file's header says so, the B-rep of a STEP file when OCP is installed
    """

    mesh: object
    source: str = "<mesh>"
    warnings: list = field(default_factory=list)
    surface: ParametricSurface | None = None
    units: str = "mm"
    unit_warning: str | None = None
    _corners: tuple | None = field(default=None, init=False, repr=False, compare=False)
    _edges: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    _vertex_tree: object = field(default=None, init=False, repr=False, compare=False)

    def edges(self, crease_deg=CREASE_ANGLE_DEG):
        """The mesh's creases, outline and holes (:func:`metrology.panel.edges.panel_edges`), cached."""
        if crease_deg not in self._edges:
            from metrology.panel.edges import panel_edges

            self._edges[crease_deg] = panel_edges(self.mesh, crease_deg)
        return self._edges[crease_deg]

    def _vertex_corners(self):
        """Corners (face * 3 + k) sorted by vertex, and each vertex's start and count (cached)."""
        if self._corners is None:
            flat = np.asarray(self.mesh.faces).ravel()
            order = np.argsort(flat, kind="stable")
            count = np.bincount(flat, minlength=len(self.mesh.vertices))
            start = np.concatenate([[0], np.cumsum(count)[:-1]])
            self._corners = (order, start, count)
        return self._corners

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

    def corner_normals(self, tri, crease_deg=CREASE_ANGLE_DEG):
        """The reference normal (:meth:`reference_normal_at`) at each corner of faces ``tri``.

        Returns
        -------
        (m, 3 corners, 3) float, unit, panel frame
        """
        tri = np.asarray(tri, int)
        eye = np.eye(3)
        return np.stack([self.reference_normal_at(tri, np.broadcast_to(eye[k], (len(tri), 3)), crease_deg)[0]
                         for k in range(3)], axis=1)

    def reference_normal_at(self, tri, bary, crease_deg=CREASE_ANGLE_DEG):
        """The mesh's reference normal: the face hit, smoothed only within a crease angle.

        At each corner of the face hit, the normal is the angle-weighted mean of the normals
        of the faces around that vertex that make less than ``crease_deg`` with the face hit
        (the face itself always counts), leaving out faces whose planar region is more than
        :data:`TANGENT_AREA_RATIO` times smaller than the face hit's (a fillet's facets next
        to the wide plane it is tangent to); the three corner normals are then interpolated with
        ``bary``. A face that meets no neighbour across an edge at more than
        :data:`metrology.panel.edges.FLAT_RAD` short of a crease lies in a planar region: its
        own normal is the reference. Across an edge sharper than the crease nothing is averaged, so on a box or a
        coarsely faceted cylinder the reference is the face's own normal; on a fine mesh of a
        smooth surface it is the usual smooth-shaded normal.

        Parameters
        ----------
        tri : (m,) int, face indices (no misses)
        bary : (m, 3) float, barycentric coordinates in those faces
        crease_deg : float, deg

        Returns
        -------
        n : (m, 3) float, unit, panel frame
        faceting : (m,) float, rad, the reference's own uncertainty: half the largest angle
            between the face hit and the faces it is smoothed with (the normal turns by about
            that much across one face of the tessellated curve)
        chord_mm : (m,) float, mm, the chord error of that faceting: ``w theta / 8`` for the
            face's width ``w`` across the direction the surface bends to and that angle
            ``theta`` (``w^2 kappa / 8``)
        """
        mesh = self.mesh
        tri = np.asarray(tri, int)
        bary = np.asarray(bary, float)
        F = np.asarray(mesh.faces)
        N = np.asarray(mesh.face_normals)
        V = F[tri]  # (m, 3)
        # the faces around each corner's vertex, and which of their corners it is
        order, start, count = self._vertex_corners()
        K = int(count[V].max())
        slot = start[V][..., None] + np.arange(K)  # (m, 3, K)
        valid = np.arange(K) < count[V][..., None]
        cid = order[np.where(valid, slot, 0)]
        Gs, corner = cid // 3, cid % 3
        Ng = N[Gs]  # (m, 3, K, 3)
        cosang = np.einsum("mkgj,mj->mkg", Ng, N[tri])
        use = valid & (cosang >= math.cos(math.radians(crease_deg)))
        use |= Gs == tri[:, None, None]
        # the angle of each neighbouring face at the shared vertex
        P = np.asarray(mesh.vertices)[F[Gs]]  # (m, 3, K, 3 corners, 3)
        at = np.take_along_axis(P, corner[..., None, None], axis=3)[..., 0, :]
        e1 = np.take_along_axis(P, ((corner + 1) % 3)[..., None, None], axis=3)[..., 0, :] - at
        e2 = np.take_along_axis(P, ((corner + 2) % 3)[..., None, None], axis=3)[..., 0, :] - at
        # a neighbour from a planar region far narrower than the face hit's (a fillet's facet
        # next to the wide plane it is tangent to) says nothing of the plane's normal
        region = self.edges(crease_deg).region_area
        narrow = region[Gs] * TANGENT_AREA_RATIO < region[tri][:, None, None]
        w = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=-1), np.sum(e1 * e2, axis=-1)) * (use & ~narrow)
        cn = np.einsum("mkg,mkgj->mkj", w, Ng)
        cn /= np.linalg.norm(cn, axis=2, keepdims=True)
        n = np.einsum("mk,mkj->mj", bary, cn)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        sinang = np.linalg.norm(np.cross(Ng, N[tri][:, None, None, :]), axis=3)
        ang = np.where(use & ~narrow, np.arctan2(sinang, cosang), 0.0).reshape(len(tri), -1)
        j = np.argmax(ang, axis=1)
        theta = ang[np.arange(len(tri)), j]
        # the sag of the face across the direction its neighbour bends to: width * theta / 8
        bend = Ng.reshape(len(tri), -1, 3)[np.arange(len(tri)), j]
        bend = bend - np.sum(bend * N[tri], axis=1, keepdims=True) * N[tri]
        bend /= np.maximum(np.linalg.norm(bend, axis=1, keepdims=True), 1e-300)
        tri_v = np.asarray(mesh.vertices)[V]
        width = np.ptp(np.einsum("mkj,mj->mk", tri_v, bend), axis=1)
        # a face inside a planar region is its own exact reference (a long triangle of a flat
        # face that touches a tangent fillet at one corner must not lean towards it)
        flat = ~self.edges(crease_deg).curved[tri]
        n[flat] = N[tri[flat]]
        theta[flat] = 0.0
        return n, theta / 2.0, width * theta / 8.0


def _surface_from_header(text: str):
    m = re.search(r"metro-panel kind=(\w+)(?: radius_mm=([0-9.eE+-]+))?", text or "")
    if not m:
        return None
    try:
        return ParametricSurface(m.group(1), float(m.group(2)) if m.group(2) else math.inf)
    except ValueError:
        return None


def _step_unit(path):
    """The length unit a STEP file declares (``"mm"``, ``"m"``, ``"in"``, ...) or None."""
    try:
        with open(path, "rb") as fh:
            text = fh.read(2_000_000).decode("latin-1").upper()
    except OSError:
        return None
    if re.search(r"CONVERSION_BASED_UNIT\s*\(\s*'INCH'", text):
        return "in"
    m = re.search(r"SI_UNIT\s*\(\s*(\.\w+\.|\$)\s*,\s*\.METRE\.\s*\)", text)
    if m:
        return {".MILLI.": "mm", ".CENTI.": "cm", "$": "m"}.get(m.group(1))
    return None


def _declared_units(mesh, path):
    """The unit a mesh file declares: trimesh's ``units`` (glTF: metres by specification;
    3MF, ...), or a ``units<name>`` tag in the file name (trimesh's convention,
    ``counter.unitsmm.STL``); None when it declares none (STL, OBJ, PLY)."""
    u = _TRIMESH_UNITS.get(str(getattr(mesh, "units", None) or "").lower())
    if u:
        return u, "declared by the file"
    m = re.search(r"units[_-]?(mm|cm|m|in|inch|inches|millimeters|meters)(?=[._-]|$)", path.rsplit("/", 1)[-1].lower())
    if m:
        return _TRIMESH_UNITS.get(m.group(1), m.group(1)), f"from the file name ({m.group(0)})"
    return None, None


def load_panel(path, units=None) -> Panel:
    """Load and validate a panel mesh, in mm.

    STEP files are tessellated by OpenCASCADE (the ``cascadio`` wheel) with 1 um chords
    (:data:`STEP_TOL_LINEAR_MM`); OpenCASCADE converts the file's own unit (STEP declares
    it) into the intermediate glTF's metres, brought back to mm here. Other meshes are in
    the unit they declare (trimesh's ``units``: glTF is in metres; or a ``units<name>`` tag
    in the file name); STL, OBJ and PLY declare none and are taken as mm. ``units``
    (``mm``, ``cm``, ``m``, ``in``) overrides: the file's coordinates are in that unit.

    A panel is an open surface, not a solid: it is refused only when it is empty, when its
    faces are all degenerate, or when its winding is inconsistent and cannot be repaired.
    Degenerate and duplicate faces are dropped and reported in ``warnings``; a bounding
    box outside :data:`PLAUSIBLE_DIAGONAL_MM` adds a warning (not in mm?).

    Raises
    ------
    ValueError
        With the file name and what was wrong.
    """
    from metrology.panel._trimesh import trimesh as deferred

    trimesh = deferred()  # a STEP's library loaded only when a STEP is read

    path = str(path)
    if units is not None and units not in UNITS_MM:
        raise ValueError(f"units must be one of {', '.join(UNITS_MM)}, got {units!r}")
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
        # OpenCASCADE converts the STEP's own unit into the glTF it hands over, in metres
        declared, how = _step_unit(path), "declared by the STEP file"
        to_mm = 1000.0 if units is None else 1000.0 / UNITS_MM.get(declared or "mm") * UNITS_MM[units]
    else:
        declared, how = _declared_units(mesh, path)
        to_mm = UNITS_MM[units or declared or "mm"]
    if units is not None:
        unit_note = f"{units} (--units; the file declares {declared or 'none'})"
    elif declared is not None:
        unit_note = f"{declared} ({how})"
    else:
        unit_note = f"mm (assumed: a .{path.rsplit('.', 1)[-1].lower()} file carries no units)"
    if to_mm != 1.0:
        mesh.apply_scale(to_mm)
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
    unit_warning = None
    if not lo <= diag <= hi:
        raw = diag / to_mm
        guess = ", ".join(f"as {u}: {raw * f:.4g} mm" for u, f in UNITS_MM.items() if u != "mm" and lo <= raw * f <= hi)
        ask = ("is it in m or inch? give --units" + (f" ({guess})" if guess else "") if units is None else
               f"check the file: --units {units} was given")  # the user said the unit: do not ask again
        unit_warning = (f"{path}: bounding-box diagonal {diag:.4g} mm, units {unit_note}, is implausible for a panel "
                        f"(expected {lo:g}..{hi:g} mm); {ask}")
        warnings.append(unit_warning)
    header = mesh.metadata.get("header", "") if isinstance(mesh.metadata, dict) else ""
    surface = _surface_from_header(header)
    if is_step:
        from metrology.panel.brep import BRepSurface, ocp_available

        if ocp_available():  # the exact reference: the B-rep itself (OCC reads STEP into mm)
            surface = BRepSurface(path, scale=to_mm / 1000.0)
    return Panel(mesh, path, warnings, surface, unit_note, unit_warning)


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
    return centre, np.vstack([*plane_axes(n), n])


def plane_axes(n):
    """Two in-plane axes of the plane of unit normal ``n``, as CAD grids lay them out.

    ``e1`` is the panel-frame axis most in the plane, projected onto it (CAD grids follow
    the axes; the in-plane principal axes of a square panel are arbitrary); ``e2 = n x e1``.
    The same choice as :func:`metrology.core.model.direction_basis`, except that ``n`` is
    used as given, not normalised again: the grids and maps stay bit-for-bit those of
    earlier versions (renormalising moves them by about one ulp).

    Parameters
    ----------
    n : (3,) float, unit, panel frame

    Returns
    -------
    e1, e2 : (3,) float, unit, panel frame
    """
    k = int(np.argmin(np.abs(n)))
    e1 = np.eye(3)[k] - n[k] * n
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)

"""Parametric test panels (plane, cylinder, sphere, saddle) and their meshes, written as binary STL."""

from __future__ import annotations

import math
from dataclasses import dataclass
import numpy as np


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

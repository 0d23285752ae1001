"""Where on the datum a spot may fall: the measured extent, as a convex polygon in the plane.

The extent is what the tracker measured of the datum (its cloud), not the plane's equation: a
spot off the plate is no reading, or a reading of something else. It is kept as a convex
polygon in plane coordinates ``(s, t) = basis . (p - origin)`` (mm) with its half-planes
``A (s, t) <= b``, so "inside, with a margin of m mm" is ``A (s, t) <= b - m``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.plane import Plane, plane_basis

__all__ = ["DatumExtent"]


@dataclass(frozen=True)
class DatumExtent:
    """A convex region of the datum plane.

    Attributes
    ----------
    origin : (3,) float, mm, tracker frame, a point of the plane
    basis : (2, 3) float, unit, tracker frame, the in-plane axes s, t
    vertices : (k, 2) float, mm, (s, t), counter-clockwise
    source : str, where the extent came from (for the report)
    """

    origin: np.ndarray
    basis: np.ndarray
    vertices: np.ndarray
    source: str = ""

    @classmethod
    def from_points(cls, plane: Plane, points, source: str = "cloud") -> "DatumExtent":
        """The convex hull of a cloud projected on ``plane``.

        Parameters
        ----------
        plane : Plane, tracker frame
        points : (m, 3) float, mm, tracker frame, m >= 3
        """
        from scipy.spatial import ConvexHull, QhullError

        pts = np.asarray(points, float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
            raise ValueError(f"{source}: need at least 3 datum points for its extent, got shape {pts.shape}")
        basis = plane_basis(plane.normal)
        origin = -plane.offset * plane.normal
        st = (pts - origin) @ basis.T
        try:
            hull = ConvexHull(st)
        except QhullError:
            raise ValueError(f"{source}: the datum points span no area on the plane") from None
        return cls(origin, basis, st[hull.vertices], source)

    @classmethod
    def disc(cls, plane: Plane, centre, radius_mm: float, source: str = "disc", sides: int = 64) -> "DatumExtent":
        """A disc of ``radius_mm`` around ``centre`` (3,) mm (projected on the plane), as a ``sides``-gon
        inscribed in it."""
        if not radius_mm > 0:
            raise ValueError(f"extent radius {radius_mm} mm: expected a positive number")
        basis = plane_basis(plane.normal)
        origin = -plane.offset * plane.normal
        c = (np.asarray(centre, float) - origin) @ basis.T
        phi = 2 * np.pi * np.arange(sides) / sides
        return cls(origin, basis, c + radius_mm * np.stack([np.cos(phi), np.sin(phi)], axis=1), source)

    @property
    def halfplanes(self):
        """``A (k, 2)`` unit outward normals and ``b (k,)`` mm with ``A (s, t) <= b`` inside."""
        v = self.vertices
        edge = np.roll(v, -1, axis=0) - v
        A = np.stack([edge[:, 1], -edge[:, 0]], axis=1)
        A /= np.linalg.norm(A, axis=1, keepdims=True)
        b = np.sum(A * v, axis=1)
        centre = v.mean(axis=0)
        flip = A @ centre > b  # clockwise input: outward normals point in
        A[flip], b[flip] = -A[flip], -b[flip]
        return A, b

    @property
    def centre(self) -> np.ndarray:
        """(3,) float, mm, tracker frame: the vertices' mean."""
        return self.origin + self.vertices.mean(axis=0) @ self.basis

    def plane_coords(self, points) -> np.ndarray:
        """``(..., 2)`` mm plane coordinates of tracker points ``(..., 3)`` mm."""
        return (np.asarray(points, float) - self.origin) @ self.basis.T

    def inside(self, points, margin_mm: float = 0.0) -> np.ndarray:
        """``(...)`` bool: the points' projections lie inside, at least ``margin_mm`` (a number, or
        one per point) from the edge;
        False for non-finite points."""
        st = self.plane_coords(points)
        A, b = self.halfplanes
        ok = np.all(st @ A.T <= b - np.asarray(margin_mm, dtype=float)[..., None], axis=-1)
        return ok & np.all(np.isfinite(st), axis=-1)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``(n, 3)`` mm tracker points uniform over the polygon (rejection from its bounding box)."""
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        out = []
        while sum(len(o) for o in out) < n:
            st = rng.uniform(lo, hi, size=(2 * n + 16, 2))
            p = self.origin + st @ self.basis
            out.append(p[self.inside(p)])
        return np.concatenate(out)[:n]

    def to_dict(self) -> dict:
        span = self.vertices.max(axis=0) - self.vertices.min(axis=0)
        return {"source": self.source, "vertices": len(self.vertices), "span_mm": span.tolist(),
                "centre_mm": self.centre.tolist()}

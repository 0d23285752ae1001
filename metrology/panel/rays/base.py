"""The interface every ray engine implements, and what they share: the hit refined in double
precision, and the closest point on the mesh."""

from __future__ import annotations

import numpy as np


class RayCaster:
    """First hits of rays on a mesh, by one engine, refined in double precision.

    ``RayCaster(mesh, engine)`` returns the subclass of that engine (``auto``: the first
    available of :data:`metrology.panel.rays.AUTO_ORDER`), as trimesh's ``ray`` package picks
    its ``RayMeshIntersector``. An engine only finds the triangle (:meth:`_first_triangle`);
    :meth:`cast` then intersects the ray with that triangle in float64 (Moeller-Trumbore),
    so the float32 engines (embree, Open3D) give the same hit points as the double-precision
    one wherever they find the same triangle.

    Attributes
    ----------
    mesh : trimesh.Trimesh, mm, panel frame
    triangles : (f, 3, 3) float, mm, panel frame, the mesh's triangles in double precision
    engine : str, the engine's name
    """

    engine = "base"

    def __new__(cls, mesh=None, engine: str = "auto"):
        if cls is RayCaster:
            from metrology.panel.rays import engine_class

            cls = engine_class(engine)
        return super().__new__(cls)

    def __init__(self, mesh, engine: str = "auto"):
        self.mesh = mesh
        self.triangles = np.asarray(mesh.triangles, dtype=float)
        self._centre = np.asarray(mesh.bounds, float).mean(axis=0)
        self._impl = None
        self._closest_scene = None

    # -- what an engine implements -----------------------------------------------------
    def _build(self):
        """The engine's acceleration structure (stored in ``self._impl``)."""
        raise NotImplementedError

    def _first_triangle(self, origins, directions):
        """``(m,)`` int: the first triangle hit, -1 on a miss (engine precision)."""
        raise NotImplementedError

    def raw_distance(self, origins, directions):
        """Distance to the first hit as the engine computes it, inf on a miss (mm)."""
        return self.cast(origins, directions)[1]

    # -- shared ------------------------------------------------------------------------
    def build(self):
        """Build the acceleration structure (done lazily by the first query)."""
        if self._impl is not None:
            return self
        self._impl = self._build()
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
        return self._first_triangle(origins, directions)

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
            v0, v1, v2 = (self.triangles[tri[hit], k] for k in range(3))
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

    def _open3d_scene(self):
        """An Open3D scene of the mesh, centred (float32 keeps 7 digits)."""
        from metrology.io._o3d import open3d

        o3d = open3d()
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor((np.asarray(self.mesh.vertices) - self._centre).astype(np.float32)),
            o3d.core.Tensor(np.asarray(self.mesh.faces).astype(np.uint32)),
        )
        return scene

    def _closest_triangle(self, points):
        """``(m,)`` int: the triangle nearest each point (Open3D's, float32 on centred coordinates)."""
        from metrology.io._o3d import open3d

        o3d = open3d()
        if self._closest_scene is None:
            self._closest_scene = self._open3d_scene()
        ans = self._closest_scene.compute_closest_points(o3d.core.Tensor((points - self._centre).astype(np.float32)))
        return ans["primitive_ids"].numpy().astype(np.int64)

    def closest(self, points):
        """Closest points on the mesh (the engine finds the triangle, refined in double).

        Parameters
        ----------
        points : (m, 3) float, mm, panel frame

        Returns
        -------
        tri : (m,) int
        closest : (m, 3) float, mm, panel frame
        """
        import trimesh

        points = np.asarray(points, float).reshape(-1, 3)
        tri = self._closest_triangle(points)
        return tri, trimesh.triangles.closest_point(self.triangles[tri], points)

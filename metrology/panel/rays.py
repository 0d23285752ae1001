"""Ray casting on a panel: the engines (Open3D, embree, trimesh) behind one interface."""

from __future__ import annotations

import numpy as np


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

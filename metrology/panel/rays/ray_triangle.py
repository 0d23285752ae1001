"""trimesh's pure-numpy engine (an r-tree of the triangles, double precision): rays and closest points without
Open3D."""

from __future__ import annotations

import numpy as np

from metrology.panel.rays.base import RayCaster


class TriangleCaster(RayCaster):
    engine = "trimesh"

    def _build(self):
        from trimesh.ray.ray_triangle import RayMeshIntersector

        impl = RayMeshIntersector(self.mesh)
        self.mesh.triangles_tree  # noqa: B018  (the r-tree, built now)
        return impl

    def _first_triangle(self, origins, directions):
        return np.asarray(self._impl.intersects_first(origins, directions), dtype=np.int64)

    def _closest_triangle(self, points):
        from trimesh.proximity import closest_point

        return np.asarray(closest_point(self.mesh, points)[2], dtype=np.int64)

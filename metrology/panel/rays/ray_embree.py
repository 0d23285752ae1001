"""trimesh's embree engine (``embreex``, the ``fast`` extra)."""

from __future__ import annotations

import numpy as np

from metrology.panel.rays.base import RayCaster


class EmbreeCaster(RayCaster):
    engine = "embree"

    def _build(self):
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        return RayMeshIntersector(self.mesh)

    def _first_triangle(self, origins, directions):
        return np.asarray(self._impl.intersects_first(origins, directions), dtype=np.int64)

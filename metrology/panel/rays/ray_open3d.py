"""Open3D's ``RaycastingScene`` (Embree inside, float32 on centred coordinates)."""

from __future__ import annotations

import numpy as np

from metrology.panel.rays.base import RayCaster


class Open3DCaster(RayCaster):
    engine = "open3d"

    def _build(self):
        scene = self._open3d_scene()
        self._closest_scene = scene  # the same scene answers closest-point queries
        return scene

    def _rays(self, origins, directions):
        from metrology.io._o3d import open3d

        rays = np.hstack([np.asarray(origins, float) - self._centre, directions]).astype(np.float32)
        return self._impl.cast_rays(open3d().core.Tensor(rays))

    def _first_triangle(self, origins, directions):
        ids = self._rays(origins, directions)["primitive_ids"].numpy().astype(np.int64)
        ids[ids == int(self._impl.INVALID_ID)] = -1
        return ids

    def raw_distance(self, origins, directions):
        self.build()
        return self._rays(origins, directions)["t_hit"].numpy().astype(float)

"""Ray casting on a panel: one class per engine behind one interface (:class:`RayCaster`),
chosen once, as trimesh's ``ray`` package does."""

from __future__ import annotations

from metrology.panel.rays.base import RayCaster
from metrology.panel.rays.ray_embree import EmbreeCaster
from metrology.panel.rays.ray_open3d import Open3DCaster
from metrology.panel.rays.ray_triangle import TriangleCaster

#: name -> engine class
ENGINES = {cls.engine: cls for cls in (TriangleCaster, EmbreeCaster, Open3DCaster)}
#: ``auto`` picks the first available of these, ordered by the benchmark
#: (benchmarks/bench_normals.py: Open3D's RaycastingScene is fastest including its build)
AUTO_ORDER = ("open3d", "embree", "trimesh")

__all__ = ["RayCaster", "ENGINES", "AUTO_ORDER", "available_engines", "engine_class",
           "Open3DCaster", "EmbreeCaster", "TriangleCaster"]


def available_engines() -> list:
    """The ray engines usable here, among ``trimesh``, ``embree``, ``open3d``."""
    return [e for e in ENGINES if _available(e)]


def _available(engine: str) -> bool:
    """``engine`` usable here (only its own library imported: ``trimesh`` needs none beyond trimesh)."""
    if engine == "embree":
        try:
            from trimesh.ray import has_embree
        except ImportError:
            return False
        return bool(has_embree)
    if engine == "open3d":
        try:
            from metrology.io._o3d import open3d

            open3d()
        except (ImportError, OSError):
            return False
    return True


def engine_class(engine: str = "auto") -> type:
    """The :class:`RayCaster` subclass of ``engine`` (``auto``: the first of
    :data:`AUTO_ORDER` available here); ``ValueError`` naming the choices otherwise."""
    if engine == "auto":
        engine = next(e for e in AUTO_ORDER if _available(e))
    if engine not in ENGINES:
        raise ValueError(f"engine must be auto, trimesh, embree or open3d, got {engine!r}")
    if not _available(engine):
        raise ValueError(f"ray engine {engine!r} is not available here (available: {', '.join(available_engines())})")
    return ENGINES[engine]

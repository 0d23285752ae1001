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


def engine_class(engine: str = "auto") -> type:
    """The :class:`RayCaster` subclass of ``engine`` (``auto``: the first of
    :data:`AUTO_ORDER` available here); ``ValueError`` naming the choices otherwise."""
    engines = available_engines()
    if engine == "auto":
        engine = next(e for e in AUTO_ORDER if e in engines)
    if engine not in ENGINES:
        raise ValueError(f"engine must be auto, trimesh, embree or open3d, got {engine!r}")
    if engine not in engines:
        raise ValueError(f"ray engine {engine!r} is not available here (available: {', '.join(engines)})")
    return ENGINES[engine]

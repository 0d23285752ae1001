"""metro: metrology for robotic drilling.

Public names are listed in ``__all__`` and imported on first use (PEP 562 ``__getattr__``):
``import metrology`` (and any ``metrology.x.y``) loads none of the subpackages it does not use.
"""

import importlib

#: public name -> the module that defines it (imported on first use, PEP 562: `import metrology` stays cheap)
_LAZY = {
    'SensorLayout': 'metrology.core.layout',
    'load_layout': 'metrology.io.layout',
    'save_layout': 'metrology.io.layout',
    'readings': 'metrology.core.model',
    'jacobian_raw': 'metrology.core.model',
    'jacobian_tangent': 'metrology.core.model',
    'direction_from_tangent': 'metrology.core.model',
    'gauge_null_vector': 'metrology.core.model',
    'projection_points': 'metrology.core.normals',
    'normal_eq18': 'metrology.core.normals',
    'normal_lsq': 'metrology.core.normals',
    'micro_plane_normal': 'metrology.core.normals',
    'attitude_angles': 'metrology.core.normals',
    'normal_from_angles': 'metrology.core.normals',
    'angle_between': 'metrology.core.normals',
    'Plane': 'metrology.core.plane',
    'fit_plane_tls': 'metrology.core.plane',
    'PlaneFit': 'metrology.datum',
    'fit_plane_robust': 'metrology.datum',
    'fit_plane_file': 'metrology.jobs.fit_plane',
    'read_cloud': 'metrology.io.clouds',
    'CalibrationReport': 'metrology.calibration.calibrate',
    'calibrate_dataset': 'metrology.calibration.calibrate',
    'validate': 'metrology.calibration.validation',
    'fit_algebraic_sphere': 'metrology.core.sphere',
    'micro_sphere_normal': 'metrology.core.sphere',
    'load_panel': 'metrology.panel.mesh',
    'run_normals': 'metrology.panel.run',
    'diagnose': 'metrology.diagnosis',
}


def lazy_names(module: str, names: dict, namespace: dict):
    """A package's PEP 562 ``__getattr__`` and ``__dir__``: ``names`` (public name -> the module that
    defines it) imported on first use and kept in ``namespace`` (the package's ``globals()``)."""

    def __getattr__(name):
        if name in names:
            value = getattr(importlib.import_module(names[name]), name)
            namespace[name] = value
            return value
        raise AttributeError(f"module {module!r} has no attribute {name!r}")

    def __dir__():
        return sorted(set(namespace) | set(names))

    return __getattr__, __dir__


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())


__all__ = [
    "SensorLayout", "load_layout", "save_layout",
    "readings", "jacobian_raw", "jacobian_tangent", "direction_from_tangent", "gauge_null_vector",
    "projection_points", "normal_eq18", "normal_lsq", "micro_plane_normal", "attitude_angles",
    "normal_from_angles", "angle_between",
    "Plane", "fit_plane_tls", "PlaneFit", "fit_plane_robust", "fit_plane_file", "read_cloud",
    "CalibrationReport", "calibrate_dataset", "validate",
    "load_panel", "run_normals", "micro_sphere_normal", "fit_algebraic_sphere",
    "diagnose",
]

__version__ = "0.1.0"

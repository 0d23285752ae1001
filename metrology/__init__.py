"""metro: metrology for robotic drilling.

Public names are listed in ``__all__``. Heavy libraries (Open3D, trimesh, scipy, filterpy,
matplotlib) are imported inside the functions that need them, so importing this package
is cheap.
"""

from metrology.core.layout import SensorLayout
from metrology.io.layout import load_layout, save_layout
from metrology.core.model import readings, jacobian_raw, jacobian_tangent, direction_from_tangent, gauge_null_vector
from metrology.core.normals import projection_points, normal_eq18, normal_lsq, micro_plane_normal, attitude_angles, normal_from_angles, angle_between
from metrology.core.plane import Plane, fit_plane_tls
from metrology.datum import PlaneFit, fit_plane_robust
from metrology.jobs.fit_plane import fit_plane_file
from metrology.io.clouds import read_cloud
from metrology.calibration.calibrate import CalibrationReport, calibrate_dataset
from metrology.calibration.validation import validate
from metrology.core.sphere import fit_algebraic_sphere, micro_sphere_normal
from metrology.panel.mesh import load_panel
from metrology.panel.run import run_normals
from metrology.diagnosis.decide import diagnose

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

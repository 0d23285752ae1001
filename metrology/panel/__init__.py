"""CAD panels: test surfaces, meshes, ray engines, drilling points, the head and the attitude loop.

The words and figures of a run live in :mod:`metrology.report.normals`; the file job in
:mod:`metrology.jobs.normals`; the micro-sphere in :mod:`metrology.core.sphere`.
"""

from metrology.panel.attitude import STATUS, MotionError, attitude_loop
from metrology.panel.brep import BRepSurface, ocp_available
from metrology.panel.edges import PanelEdges, footprint_radius, panel_edges, straddle
from metrology.panel.head import cast_beams, default_standoff, place_head, tilted_feed, tool_axis_tcs
from metrology.panel.mesh import UNITS_MM, Panel, load_panel, panel_plane, plane_axes
from metrology.panel.points import DrillPoints, grid_points, read_points, snap_points
from metrology.panel.rays import RayCaster, available_engines
from metrology.panel.run import NormalsRun, run_normals
from metrology.panel.surfaces import ParametricSurface, panel_mesh, write_binary_stl

__all__ = [
    "ParametricSurface", "panel_mesh", "write_binary_stl",
    "Panel", "load_panel", "panel_plane", "plane_axes", "UNITS_MM",
    "PanelEdges", "panel_edges", "footprint_radius", "straddle", "BRepSurface", "ocp_available",
    "RayCaster", "available_engines",
    "DrillPoints", "read_points", "grid_points", "snap_points",
    "tool_axis_tcs", "default_standoff", "place_head", "tilted_feed", "cast_beams",
    "MotionError", "attitude_loop", "STATUS",
    "NormalsRun", "run_normals",
]

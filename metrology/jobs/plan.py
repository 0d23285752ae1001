"""``metro plan`` as a job: the nominal layout and the datum in, the poses to take out.

The poses are written in the tracker-export contract (``pose_id,x,y,z,qw,qx,qy,qz`` with empty
``d_<sensor>`` columns): the cell fills the readings, and the same file goes to
``metro calibrate``.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from metrology.plan import DatumExtent, Limits, PosePlan, plan_poses

__all__ = ["plan_files", "plan_export", "layout_tolerance", "TOOL_SIDES"]

#: ``--tool-side``: the tool is on the side of the datum its normal points to, or against it
TOOL_SIDES = {"normal": 1.0, "against": -1.0}


def _extent(plane, points, plane_path, extent_path, extent_radius_mm) -> DatumExtent:
    from metrology.io.clouds import read_cloud

    if extent_path is not None:
        return DatumExtent.from_points(plane, read_cloud(extent_path), str(extent_path))
    if points is not None:
        return DatumExtent.from_points(plane, points, f"{plane_path} (inliers)")
    if extent_radius_mm is not None:
        try:
            centre = json.loads(Path(plane_path).read_text(encoding="utf-8"))["centroid"]
        except (KeyError, ValueError, OSError):
            raise ValueError(f"{plane_path}: no 'centroid' to centre --extent-radius-mm on: give the datum cloud "
                             "with --extent") from None
        return DatumExtent.disc(plane, centre, extent_radius_mm, f"disc of {extent_radius_mm:g} mm around the centroid")
    raise ValueError(f"{plane_path}: a plane JSON carries no extent: give the datum cloud (--plane CLOUD or "
                     "--extent CLOUD) or --extent-radius-mm")


def plan_export(plan: PosePlan):
    """The planned poses as a :class:`~metrology.io.export.TrackerExport` with no readings."""
    from metrology.core.frames import quaternion_from_matrix
    from metrology.io.export import TrackerExport

    poses = plan.planned.poses
    p, n = len(poses), plan.layout.n
    width = max(3, len(str(p)))
    ids = tuple(f"P{k + 1:0{width}d}" for k in range(p))
    return TrackerExport(ids, np.full(p, np.nan), np.full(p, np.nan), quaternion_from_matrix(poses.rot), poses.trans,
                         plan.layout.names, np.full((p, n), np.nan))


def layout_tolerance(layout_path, given=None):
    """``(zero_mm, direction_deg)``: the layout's stated uncertainty, ``given`` (``--layout-tolerance``)
    or the layout file's ``[tolerance]`` table (``zero_mm``: each zero-point coordinate, mm;
    ``direction_deg``: each beam's angle from its nominal direction, deg), else ``(0, 0)``."""
    import tomllib

    where = "--layout-tolerance"
    if given is None:
        try:
            with open(layout_path, "rb") as fh:
                table = tomllib.load(fh).get("tolerance")
        except (OSError, tomllib.TOMLDecodeError):
            table = None  # load_layout says what is wrong with the file
        if table is None:
            return 0.0, 0.0
        where = f"{layout_path}: [tolerance]"
        if not isinstance(table, dict) or set(table) - {"zero_mm", "direction_deg"}:
            raise ValueError(f"{where}: expected a table of zero_mm and direction_deg, got {table!r}")
        given = (table.get("zero_mm", 0.0), table.get("direction_deg", 0.0))
    zero, direction = given
    for value, name in ((zero, "zero_mm"), (direction, "direction_deg")):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < (90 if name == "direction_deg" else 1e3):
            raise ValueError(f"{where}: {name} {value!r}, expected a number >= 0 (mm; deg below 90)")
    return float(zero), float(direction)


def plan_files(layout_path, plane_path, n_poses: int, tilt_max_deg: float = 10.0, standoff_mm=None,
               working_standoff_mm=None, noise_mm=None, range_mm=None, extent_path=None, extent_radius_mm=None,
               reading_margin_mm: float = 2.0, spot_margin_mm: float = 5.0, robot_error_mm: float = 1.0,
               robot_error_deg: float = 0.1, tool_side: str = "normal", candidates: int = 5000, seed: int = 0,
               out=None, plot=None, separate=(), layout_tolerance_given=None) -> PosePlan:
    """Plan ``n_poses`` calibration poses and write them (CSV, atomically) and the curve figure.

    ``noise_mm`` and ``range_mm`` (mm, min and max) replace the layout's; ``standoff_mm`` (min,
    max) defaults to the sensors' common range less the reading margin; ``separate`` names causes
    the design must also tell from the sensor parameters (:data:`metrology.plan.plan.SEPARABLE`).
    The poses keep their limits on every layout within the layout's stated uncertainty
    (:func:`layout_tolerance`: ``layout_tolerance_given`` = ``(zero_mm, direction_deg)`` or the
    layout file's ``[tolerance]``); the plan says what that costs (``PosePlan.tolerance_cost``).
    Errors are ValueError naming the file or value; nothing is written unless the plan succeeds.
    """
    from metrology.calibration.dataset import load_plane
    from metrology.io.export import write_export
    from metrology.io.layout import load_layout

    if tool_side not in TOOL_SIDES:
        raise ValueError(f"--tool-side {tool_side!r}: expected one of {', '.join(TOOL_SIDES)}")
    if not 0 < tilt_max_deg < 60:
        raise ValueError(f"--tilt-max-deg {tilt_max_deg:g}: expected a number in (0, 60) deg")
    if candidates < n_poses:
        raise ValueError(f"--candidates {candidates}: fewer than --poses {n_poses}")
    for path, what in ((out, "poses CSV"), (plot, "curve figure")):
        if path is not None and not Path(path).resolve().parent.is_dir():
            raise ValueError(f"{path}: directory {Path(path).parent} does not exist (for the {what})")
    layout = load_layout(layout_path)
    from metrology.core.effects.terms import refuse_terms

    refuse_terms(layout, layout_path, "plan", "its design and predicted sigmas are of the sensors' five parameters")
    if noise_mm is not None:
        layout = replace(layout, noise_mm=np.full(layout.n, float(noise_mm)))
    if range_mm is not None:
        layout = replace(layout, range_mm=np.tile(np.asarray(range_mm, float), (layout.n, 1)))
    if not np.all(np.isfinite(layout.noise_mm)):
        raise ValueError(f"{layout_path}: no noise_mm for every sensor: give --noise-mm")
    if not np.all(np.isfinite(layout.range_mm)):
        raise ValueError(f"{layout_path}: no range_mm for every sensor: give --range-mm MIN,MAX")
    if standoff_mm is None:
        standoff_mm = (float(layout.range_mm[:, 0].max()) + reading_margin_mm,
                       float(layout.range_mm[:, 1].min()) - reading_margin_mm)
    if not standoff_mm[0] < standoff_mm[1]:
        raise ValueError(f"stand-off {standoff_mm[0]:g}-{standoff_mm[1]:g} mm: expected min < max (the range less "
                         f"the {reading_margin_mm:g} mm margin is empty?)")
    tol_zero_mm, tol_direction_deg = layout_tolerance(layout_path, layout_tolerance_given)
    plane, points = load_plane(plane_path)
    extent = _extent(plane, points, plane_path, extent_path, extent_radius_mm)
    limits = Limits(float(np.deg2rad(tilt_max_deg)), tuple(map(float, standoff_mm)), layout.range_mm,
                    float(reading_margin_mm), float(spot_margin_mm), float(np.deg2rad(robot_error_deg)),
                    TOOL_SIDES[tool_side], tol_zero_mm, float(np.deg2rad(tol_direction_deg)))
    plan = plan_poses(layout, plane, extent, int(n_poses), limits, layout.noise_mm, np.random.default_rng(seed),
                      working_standoff_mm, int(candidates), float(robot_error_mm), float(np.deg2rad(robot_error_deg)),
                      seed=seed, separate=tuple(separate))
    if plot is not None:
        from metrology.report.plan import plot_plan_curve

        plot_plan_curve(plan, plot)
    if out is not None:
        write_export(plan_export(plan), out)
    return plan

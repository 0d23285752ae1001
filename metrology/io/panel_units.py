"""The unit of a panel and its hole table, judged together against the head (mm) that drills them.

A 1200 x 800 mm skin exported in inches reads as a 47 x 31 mm part; its table's holes, 100 mm
apart, as 3.9 mm apart. Each file alone looks like a part (the mesh's diagonal check in
:mod:`metrology.panel.mesh` passes it), and a run on it measures nothing, or worse, curvatures
25 times too large. The layout is in mm (the calibration's own file), so the head is the
yardstick: the rule (:func:`check_panel_units`) reads the panel's and the table's numbers as mm
and refuses them when

- the panel is narrower than the head's footprint (:data:`FOOTPRINT_FIT`): the spots around a
  hole cannot all land on it, so no hole could be measured. Its longest side is held to that always;
  its second side only where the panel is nearly flat (its depth under :data:`FLAT_DEPTH` of that
  side): a leading edge or a tube of R 20 is narrow across, deep, and drilled (its holes then
  ``not_measured`` with their own reason), while a skin in inches is narrow and flat;
- the table's holes are closer than :data:`MIN_PITCH_MM` (median distance to the nearest hole),
  or farther than :data:`MAX_PITCH_MM`: no drilled pattern;
- the table's holes spread wider than the panel (:data:`TABLE_OVER_PANEL`): the two files are
  not in one unit;
- the log's commanded positions (``pose_x_mm``, ...) lie farther from their holes' table points
  than :data:`POSE_REACH` stand-offs: the table is not in the log's unit.

The refusal names the unit that would make every reading plausible (``in`` or ``m``, read with
:data:`CANDIDATES`) and the fix (``--units``, or converting the files). Numbers that no other unit
makes plausible either are let through (a dense test pattern is no unit's mistake), unless the panel
is narrower than the footprint (nothing could be measured on it) or the log's commanded positions lie
that far from their holes' points in every unit: then the table is another panel's whose hole_ids the
log shares (H0001 is every table's first hole), or the positions are not in the panel's frame, and
every hole would be judged on a surface it was not drilled on. Nothing here reads a file.
"""

from __future__ import annotations

import numpy as np

from metrology.io.holelog_schema import POSE_POSITION

__all__ = ["check_panel_units", "pose_rows", "log_positions", "nearest_spacing", "FOOTPRINT_FIT", "MIN_PITCH_MM", "MAX_PITCH_MM",
           "TABLE_OVER_PANEL", "POSE_REACH", "CANDIDATES", "FLAT_DEPTH"]

#: the panel's sides must hold this many footprint radii (the spots' disc, both sides of a hole)
FOOTPRINT_FIT = 2.0
#: a panel whose box is shallower than this share of its second side is nearly flat (a skin's sagitta: R 1500
#: over 800 mm is 0.07 of it; a half tube's depth is half its width): only then is its second side held to the
#: footprint
FLAT_DEPTH = 0.25
#: holes closer than this (mm) cannot both be drilled: the smallest fastener (2.4 mm) at two diameters' pitch
MIN_PITCH_MM = 5.0
#: holes a median 2 m from their nearest neighbour are no hole pattern a cell drills (one hole per skin)
MAX_PITCH_MM = 2000.0
#: the table's box may exceed the panel's by this share (holes near an edge, a mesh trimmed to the part)
TABLE_OVER_PANEL = 1.1
#: a commanded position lies within this many stand-offs (plus the footprint) of its hole's table point
POSE_REACH = 4.0
#: the units tried when the numbers do not read as mm: name -> mm per unit
CANDIDATES = {"in": 25.4, "m": 1000.0, "cm": 10.0}
NAMES = {"in": "inches", "m": "metres", "cm": "centimetres"}


def nearest_spacing(points) -> float:
    """Median distance (file units) of each of ``points (m, 3)`` to its nearest other point (NaN under 2):
    :func:`metrology.io.units.median_nearest_distance`."""
    from metrology.io.units import median_nearest_distance

    return median_nearest_distance(points)


def _problems(scale, footprint_mm, standoff_mm, panel_sides, table_sides, pitch, pose_gap) -> list:
    """What is implausible when the files' numbers times ``scale`` are mm (module rule), as phrases."""
    out = []
    if panel_sides is not None and _narrow(tuple(x * scale for x in panel_sides), footprint_mm):
        out.append(f"the panel ({panel_sides[0] * scale:.3g} x {panel_sides[1] * scale:.3g} mm) is narrower than "
                   f"the head's footprint ({FOOTPRINT_FIT * footprint_mm:.3g} mm across)")
    if np.isfinite(pitch) and not MIN_PITCH_MM <= pitch * scale <= MAX_PITCH_MM:
        out.append(f"the holes are {pitch * scale:.3g} mm apart (a drilled pattern: {MIN_PITCH_MM:g} to "
                   f"{MAX_PITCH_MM:g} mm)")
    if panel_sides is not None and table_sides is not None and \
            table_sides[0] > TABLE_OVER_PANEL * panel_sides[0] + 1e-9:
        out.append(f"the holes spread {table_sides[0] * scale:.3g} mm, wider than the panel "
                   f"({panel_sides[0] * scale:.3g} mm)")
    gap = _far(None if pose_gap is None else (lambda s: pose_gap(s * scale)), footprint_mm, standoff_mm)
    if gap is not None:
        out.append(f"the log's commanded positions lie a median {gap:.3g} mm from their holes' points "
                   f"(the stand-off is {standoff_mm:.3g} mm)")
    return out


def _far(pose_gap, footprint_mm, standoff_mm):
    """The median gap (mm) of the commanded positions from their holes' points where it is beyond
    :data:`POSE_REACH` stand-offs plus the footprint (the files' numbers read as mm), else None."""
    if pose_gap is None:
        return None
    gap = pose_gap(1.0)
    return gap if np.isfinite(gap) and gap > POSE_REACH * standoff_mm + footprint_mm else None


def _narrow(sides, footprint_mm) -> bool:
    """The panel of box ``sides`` (mm, largest first) cannot hold a footprint (module rule: its second side only
    where it is nearly flat, :data:`FLAT_DEPTH`)."""
    fit = FOOTPRINT_FIT * footprint_mm
    return sides[0] < fit or (sides[1] < fit and sides[2] < FLAT_DEPTH * sides[1])


def _sides(extent):
    """The three sides of a box, largest first (file units)."""
    e = np.sort(np.asarray(extent, float))[::-1]
    return float(e[0]), float(e[1]), float(e[2])


def pose_rows(table_ids, keys):
    """Each sampled log row's row in the hole table (-1: not in it): ``table_ids (m,)`` against the log's join keys
    ``keys (q,)`` (``point_id``, else ``hole_id``; :func:`metrology.io.holelog_sample.commanded_positions`)."""
    index = {str(h): i for i, h in enumerate(table_ids)}
    return np.fromiter((index.get(str(k), -1) for k in keys), dtype=np.intp, count=len(keys))


def log_positions(log, table_ids):
    """``(positions (q, 3), rows (q,))``: the first commanded positions of ``log`` (a hole log,
    :func:`metrology.io.holelog_sample.commanded_positions`) and each one's row in the hole table (-1: not in it),
    the input :func:`check_panel_units` takes as ``pose_points`` and ``pose_at``; ``(None, None)`` when the log
    carries no position."""
    from metrology.io.holelog_sample import commanded_positions

    sample = None if log is None else commanded_positions(log)
    if sample is None:
        return None, None
    keys, xyz = sample
    return xyz, pose_rows(table_ids, keys)


def check_panel_units(footprint_mm, standoff_mm, *, panel_extent=None, table_points=None, pose_points=None,
                      names="the panel", given=None, panel_in_mm=False, units_option=True, pose_at=None,
                      log_name="the log"):
    """A one-line refusal when the panel, the hole table and the log's commanded positions do not read as mm
    against the head, else None.

    Parameters
    ----------
    footprint_mm : float, mm, the head's footprint radius (the layout's spots at mid-range)
    standoff_mm : float, mm, the readings' stand-off (mid-range)
    panel_extent : (3,) float, file units (mm once loaded), the panel's bounding box, or None
    table_points : (m, 3) float, file units, the hole table's drill points, or None
    pose_points : (q, 3) float, as the log writes them (mm by their names), the log's commanded TCS positions in
        the panel frame, or None when the log carries none; row i belongs to the table's row ``pose_at[i]``
        (None: the rows of ``table_points`` themselves; -1: a hole not in the table, left out)
    names : str, how the refusal names the files ("skin.stl and skin.holes.csv")
    given : str or None, the ``--units`` the user gave (the refusal then asks to check the files)
    panel_in_mm : bool, the panel's unit is settled (a file that declares it, or ``--units``): only
        the table is scaled when a candidate unit is tried
    units_option : bool, the command takes ``--units`` (the refusal offers it; else: convert the files)
    pose_at : (q,) int or None, each commanded position's row of ``table_points`` (:func:`pose_rows`)
    log_name : str, how the refusal names the log when its positions alone are in another unit
    """
    panel_sides = None if panel_extent is None else _sides(panel_extent)
    table_sides = None
    pitch = float("nan")
    gap = None
    if table_points is not None and len(table_points):
        T = np.asarray(table_points, float)
        table_sides = _sides(np.percentile(T, 100, axis=0) - np.percentile(T, 0, axis=0))
        pitch = nearest_spacing(T)
        gap = _pose_gap(T, pose_points, pose_at)
    problems = _problems(1.0, footprint_mm, standoff_mm, panel_sides, table_sides, pitch, _at(gap, 1.0, 1.0))
    if not problems:
        return None
    # a panel that reads as mm on its own (or declares its unit) stays: only the table is tried in another unit
    settled = given is not None or panel_in_mm or (
        panel_sides is not None and not _problems(1.0, footprint_mm, standoff_mm, panel_sides, None, float("nan"), None))

    def plausible(files, poses):
        """No problem left when the files' numbers are in unit ``files`` and the positions in ``poses`` (None: mm)."""
        k = CANDIDATES.get(files, 1.0)
        ps = None if panel_sides is None else panel_sides if settled else tuple(x * k for x in panel_sides)
        ts = None if table_sides is None else tuple(x * k for x in table_sides)
        return not _problems(1.0, footprint_mm, standoff_mm, ps, ts, pitch * k, _at(gap, k, CANDIDATES.get(poses, 1.0)))

    # the files' unit first (the positions in mm), then the positions' (the files in mm, or in theirs)
    files_units = [None] if given is not None else [None, *CANDIDATES]
    pose_units = [None] if gap is None else [None, *CANDIDATES]
    likely = [(f, q) for f in files_units for q in pose_units if (f, q) != (None, None) and plausible(f, q)]
    if given is not None:
        fix = (_pose_fix(likely[0][1], False) if likely else
               "check the files' unit (the layout and the log are in mm)")
        return f"{names}: read in {given} (--units {given}): {'; '.join(problems)}: {fix}"
    far = _far(_at(gap, 1.0, 1.0), footprint_mm, standoff_mm)
    if not likely and far is not None:  # no unit brings the positions to their holes: another panel's table
        return (f"{log_name}: the log's commanded positions lie a median {far:.3g} mm from their holes' points in "
                f"{names} (the stand-off is {standoff_mm:.3g} mm) and no unit brings them closer: is it this panel's "
                f"table (hole_ids another table shares?), and are {', '.join(POSE_POSITION)} in the panel's frame?")
    if not likely and not (panel_sides is not None and _narrow(panel_sides, footprint_mm)):
        return None  # odd numbers, but no other unit explains them (a dense test pattern): not a unit's mistake
    files, poses = likely[0] if likely else (None, None)
    if not likely:
        fix = "no unit reads plausibly: are these the panel and the table of this head's cell?"
    elif files is None:  # the files read as mm: the log's positions alone are in another unit
        return f"{log_name}: {'; '.join(problems)}, the holes of {names}: {_pose_fix(poses, False)}"
    elif settled and table_sides is not None and panel_sides is not None:
        fix = (f"the hole table is not in mm, it looks like {NAMES[files]} (the panel like mm): convert the table "
               f"to mm" + (
               " (--units applies to both files)" if units_option else ""))
    else:
        fix = (f"they look like {NAMES[files]}: give --units {files}, or convert them to mm" if units_option
               else f"they look like {NAMES[files]}: convert them to mm")
    if files is not None and poses is not None:
        fix += "; " + _pose_fix(poses, poses == files)
    return f"{names} read as mm: {'; '.join(problems)}: {fix}"


def _pose_gap(T, pose_points, pose_at):
    """The median distance (mm) of the commanded positions from their holes' table points as a function of the
    table's and the positions' scales, or None without positions matched to the table."""
    if pose_points is None or not len(pose_points):
        return None
    Q = np.asarray(pose_points, float)
    rows = np.arange(len(Q)) if pose_at is None else np.asarray(pose_at, np.intp)
    ok = rows >= 0
    ok[ok] = np.all(np.isfinite(Q[ok]), axis=1) & np.all(np.isfinite(T[rows[ok]]), axis=1)
    if not ok.any():
        return None
    P, Q = T[rows[ok]], Q[ok]

    def gap(table_scale, pose_scale):
        return float(np.median(np.linalg.norm(pose_scale * Q - table_scale * P, axis=1)))

    return gap


def _at(gap, table_scale, pose_scale):
    """The pose-gap phrase's input for :func:`_problems`: the gap with the positions' scale fixed."""
    return None if gap is None else (lambda s: gap(s * table_scale, pose_scale))


def _pose_fix(unit, too) -> str:
    """The fix for commanded positions that read in ``unit`` (a key of :data:`CANDIDATES`)."""
    return (f"the log's commanded positions ({', '.join(POSE_POSITION)}) look like {NAMES[unit]}"
            f"{' too' if too else ''}: write them in mm, as their names say (--units applies to the panel and "
            f"the table only)")

"""The per-hole table ``metro measure`` writes: :data:`OUTPUT_COLUMNS` in the file's units (angles in deg,
the misfit in µm, a figure not known blank), with the panel's columns where the panel is known, then the
log's columns that name the hole (:func:`passes_through`; not metro's inputs: readings, temperature, pose)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from metrology.io.arrays import from_numpy, strings
from metrology.io.holelog_schema import NUMERIC
from metrology.measure.batch import STATUSES
from metrology.measure.measured import patterns

if TYPE_CHECKING:
    from metrology.core.layout import SensorLayout
    from metrology.measure.placement import Placed

__all__ = ["OUTPUT_COLUMNS", "result_table", "passes_through"]

#: the per-hole columns metro writes, in order (before the columns passed through)
OUTPUT_COLUMNS = ("hole_id", "normal_x", "normal_y", "normal_z", "angle_deg", "U95_angle_deg", "angle_after_deg",
                  "U95_after_deg", "fit_residual_um", "fit_residual_after_um", "sensors_used", "status", "reason")


def passes_through(name: str) -> bool:
    """Whether the log's column ``name`` is written to the results: the hole's identity and labels (``hole_id``,
    ``time``, ``cell``, ``panel``, ``point_id``, hive keys, a column of the cell's own) are; what metro reads as
    its input is not (the readings ``d_*``, ``temperature_c``, the commanded pose ``pose_*``): it stays in the log,
    joined to the results by ``hole_id`` or by row (the results keep the log's row order, one row per hole)."""
    return not name.startswith("d_") and name not in NUMERIC


def _num(x):
    """A float64 column, NaN (nothing to say) as null: blank in CSV."""
    return from_numpy(np.asarray(x, np.float64), nan_is_null=True)


def _labels(codes, labels):
    """A pyarrow string array of ``labels[codes]``."""
    return strings(list(labels)).take(from_numpy(np.asarray(codes)))


def _sensor_sets(layout: "SensorLayout", used, min_sensors: int):
    """Each hole's ``sensors_used`` from ``used`` (N, n) bool: the names of the sensors its normal rests on, ""
    for fewer than ``min_sensors`` (no plane)."""
    code = patterns(used)
    names = [" ".join(nm for j, nm in enumerate(layout.names) if (p >> j) & 1) if bin(p).count("1") >= min_sensors
             else "" for p in range(1 << layout.n)]
    return _labels(code, names)


def result_table(layout: "SensorLayout", table, ids, code, reason, before, after, shown, placed: "Placed | None",
                 surf, readings, min_sensors: int, no_surface=None):
    """pyarrow.Table: a batch's results as written.

    Parameters
    ----------
    layout : SensorLayout; table : pyarrow.Table, the batch of the log; ids : its ``hole_id`` as strings
    code : (N,) int8, each hole's status; reason : pyarrow StringArray (N,)
    before, after : the holes measured before and after the adjustment (``after`` None: no after-readings);
        their ``normal``, ``residual``, ``used`` and, with the panel, ``extra`` are read
    shown : four (N,) float arrays, rad, blank where not shown: the angle and U95 before, after
    placed : Placed or None, the surfaces (the panel known); surf : HoleSurfaces or None
    readings : (N, n) float, mm, the readings before (the check against the CAD)
    min_sensors : int, the fewest readings that give a plane (fewer: ``sensors_used`` blank)
    no_surface : (N,) bool or None, with the panel known: the holes with no local surface (not in the table, or
        their footprint off the panel; ``holes._not_in_table``): no normal nor panel figure (the micro-plane's
        would show as metro's)
    """
    import pyarrow as pa

    N = len(code)
    nan = np.full(N, np.nan)
    before_angle, before_u, after_angle, after_u = shown
    lost = no_surface if no_surface is not None and no_surface.any() else None
    normal = before.normal if lost is None else np.where(lost[:, None], np.nan, before.normal)
    cols = {
        "hole_id": ids,
        "normal_x": _num(normal[:, 0]), "normal_y": _num(normal[:, 1]), "normal_z": _num(normal[:, 2]),
        "angle_deg": _num(np.degrees(before_angle)), "U95_angle_deg": _num(np.degrees(before_u)),
        "angle_after_deg": _num(np.degrees(after_angle)), "U95_after_deg": _num(np.degrees(after_u)),
        "fit_residual_um": _num(before.residual * 1e3),
        "fit_residual_after_um": _num(after.residual * 1e3 if after is not None else nan),
        "sensors_used": _sensor_sets(layout, before.used, min_sensors),
        "status": _labels(code, [str(s) for s in STATUSES]),
        "reason": reason,
    }
    if placed is not None:  # the panel's columns
        from metrology.measure.pose import against_cad

        table_row = placed.table_row
        have = table_row >= 0
        k = surf.k[table_row] if have.all() else np.where(have[:, None], surf.k[table_row], np.nan)
        cols["k1_per_mm"], cols["k2_per_mm"] = _num(k[:, 0]), _num(k[:, 1])
        cols["correction_deg"], cols["panel_misfit_per_mm"], cols["panel_misfit_z"] = (
            _num(a if lost is None else np.where(lost, np.nan, a)) for a in (
                np.degrees(before.extra.correction), before.extra.panel_misfit, before.extra.panel_misfit_z))
        if placed.pose is not None and surf.point is not None:
            vs_cad, offset = against_cad(layout, readings, before.normal, placed.shape, surf, table_row, placed.pose)
            cols["normal_vs_cad_deg"] = _num(np.degrees(vs_cad))
            cols["cad_offset_mm"] = _num(offset)
    for k in table.column_names:
        if k not in cols and passes_through(k):
            cols[k] = table.column(k)
    return pa.table(cols)

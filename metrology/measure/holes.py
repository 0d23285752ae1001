"""One batch of a hole log measured: per hole the normal, the angle, its U95 and a verdict (:func:`measure_batch`).

The rules that decide a hole's ``status``, in the order they apply, and their thresholds are
:mod:`metrology.measure.rules` (re-exported here); each pose's holes are measured, rules 1 to 2b applied, by
:mod:`metrology.measure.measured`. Here the batch: its readings taken in and the head's terms removed, both poses
measured and compared (rules 3 and 3b), the verdict (rule 4), repeated ``hole_id`` values and, with the panel,
holes its table does not have.

A hole is judged on its own row alone, so a batch's results do not depend on how the log was
split into batches or partitions (the Dask path relies on it).
"""

from __future__ import annotations

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.io.arrays import to_numpy
from metrology.io.holelog_schema import CELL, PANEL, text_codes
from metrology.measure.batch import CODE, STATUSES, ChartRows, HoleBatch, Labels, Status, blanked
from metrology.measure.columns import OUTPUT_COLUMNS, result_table
from metrology.measure.effects import apply_terms
from metrology.measure.measured import any_col, measure_pose
from metrology.measure.placement import place
from metrology.measure.reasons import reason_column, verdict_reasons
from metrology.measure.rules import (CHANGE_SIGMAS, DEFAULT_MIN_RADIUS_MM, EDGE_SIGMAS, GROSS_SIGMAS, MAX_INCIDENCE_DEG,
                                     MAX_SPOT_TURN_DEG, MIN_SENSORS, Settings, poses_disagree, verdict)

__all__ = ["Status", "STATUSES", "CODE", "Settings", "HoleBatch", "ChartRows", "measure_batch", "MIN_SENSORS", "GROSS_SIGMAS", "OUTPUT_COLUMNS",
           "EDGE_SIGMAS", "CHANGE_SIGMAS",
           "DEFAULT_MIN_RADIUS_MM", "MAX_SPOT_TURN_DEG", "MAX_INCIDENCE_DEG"]


def _readings(table, names, suffix=""):
    """(N, n) float, mm: the ``d_<sensor><suffix>`` columns, nulls as NaN."""
    cols = [table.column(f"d_{s}{suffix}") for s in names]
    return np.stack([to_numpy(c).astype(float, copy=False) for c in cols], axis=1)


def _duplicates(ids):
    """Rows (int array) whose ``hole_id`` repeats an earlier row of the batch, and that row."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if len(ids) < 2 or pc.all(pc.greater(ids.slice(1), ids.slice(0, len(ids) - 1))).as_py() \
            or len(pc.unique(ids)) == len(ids):  # the usual: ids rising (0.006 s per 1e6, a hash 0.21 s) or no repeat
        return np.zeros(0, int), np.zeros(0, int)
    counts = pc.value_counts(ids)
    repeated = counts.field("values").filter(pc.greater(counts.field("counts"), 1))
    rows = np.flatnonzero(pc.is_in(ids, value_set=repeated).to_numpy(zero_copy_only=False))
    seen, dup, orig = {}, [], []
    for r, v in zip(rows, pa.array(ids).take(pa.array(rows)).to_pylist()):
        if v in seen:
            dup.append(r)
            orig.append(seen[v])
        else:
            seen[v] = r
    return np.array(dup, int), np.array(orig, int)


def measure_batch(layout: SensorLayout, table, settings: Settings) -> HoleBatch:
    """Measure one batch of a hole log.

    Parameters
    ----------
    layout : SensorLayout, the calibrated layout (its ``covariance`` propagated when present)
    table : pyarrow.Table, the log's rows: ``hole_id`` (string); ``d_<sensor>`` for every sensor
        of the layout (mm, null or NaN = no reading); optional ``d_<sensor>_after``; every other
        column passes through (``time``, ``cell``, ``panel``, ``temperature_c``, ...)
    settings : Settings

    Returns
    -------
    HoleBatch
    """
    import pyarrow as pa

    names = layout.names
    surf = settings.surfaces
    placed = None if surf is None else place(surf, table, layout)
    shape = None if placed is None else placed.shape  # an incidence term: at each spot of the known surface
    d = (applied := apply_terms(layout, _readings(table, names), table, shape=shape)).d  # the head terms removed
    N = len(d)
    before = measure_pose(applied.normals_layout, d, settings, placed, effects=applied)
    if all(f"d_{s}_after" in table.column_names for s in names):
        da = (applied_after := apply_terms(layout, _readings(table, names, "_after"), table, shape=shape)).d
        after = measure_pose(applied_after.normals_layout, da, settings,
                         None if placed is None else placed.after(before.extra.turn), effects=applied_after)
        judge_after = np.isfinite(da).any(1)
    else:
        after, judge_after = None, np.zeros(N, bool)
    judged = np.where(judge_after, after.angle, before.angle) if after is not None else before.angle.copy()
    judged_u = np.where(judge_after, after.U95, before.U95) if after is not None else before.U95.copy()
    reason = before.reason
    poses = np.zeros(N, bool)
    if after is not None:
        for i in sorted(after.reason):
            if judge_after[i] and after.reason[i] != reason.get(i):  # (the same note before and after: once)
                reason[i] = (reason[i] + "; " if reason.get(i) else "") + "after the adjustment: " + after.reason[i]
        poses, diff, changed = poses_disagree(before, after, settings)
        poses &= judge_after & ~before.disagree & ~after.disagree  # rule 2 named the gross pose: no doubt left
        changed &= judge_after & ~poses & ~before.disagree & ~after.disagree
        for i in np.flatnonzero(poses).tolist():
            reason[i] = (reason[i] + "; " if reason.get(i) else "") + (
                f"not measured after the adjustment: the misfits before and after it differ by {diff[i] * 1e3:.1f} µm, "
                f"more than {GROSS_SIGMAS:g} sigmas beyond what a panel of radius >= {settings.min_radius_mm:g} mm "
                f"gives as the head tilts: one reading is gross, the drilled angle is not known")
        judged[poses] = np.nan
        judged_u[poses] = np.nan
    code = verdict(judged, judged_u, settings.tolerance, np.isfinite(before.angle) | judge_after)
    unshown = None  # rule 3b's holes: undecided for a cause their note names, not the verdict's text
    if after is not None and placed is None:  # rule 3b: a failing hole whose misfit changed beyond the noise
        unshown = changed & (code == CODE[Status.FAILS])
        if unshown.any():
            code[unshown] = CODE[Status.UNDECIDED]
            for i in np.flatnonzero(unshown).tolist():
                reason[i] = (reason[i] + "; " if reason.get(i) else "") + (
                    f"undecided after the adjustment: angle - U95 > tolerance, but the misfits before and after it "
                    f"differ by {diff[i] * 1e3:.1f} µm, more than {CHANGE_SIGMAS:g} noise sigmas (within rule 3's "
                    f"allowance): two gross after-readings whose misfits cancel in part tilt the normal by any angle, "
                    f"the failure is not shown")
    edge = np.where(judge_after, after.edge, before.edge) if after is not None else before.edge
    ids = table.column("hole_id").cast(pa.string())
    unmodelled = np.zeros(N, bool)
    if placed is not None:  # holes the table does not have, or whose footprint runs off the panel
        unmodelled = _not_in_table(table, placed, surf, code, reason)
    dup, orig = _duplicates(ids)
    if dup.size:
        code[dup] = CODE[Status.NOT_MEASURED]
        for r, o in zip(dup, orig):
            reason[int(r)] = f"duplicate hole_id (row {o + 1} of this batch has it too)"
    nan = np.full(N, np.nan)
    judged, judged_u, after_angle, after_u = blanked(nm := code == CODE[Status.NOT_MEASURED], judged, judged_u,
                                                     *((after.angle, after.U95) if after is not None else (nan, nan)))
    whole = unmodelled.copy()  # the hole itself not measured (not in the table, off the edge, a repeat): nor before
    whole[dup] = True
    before_angle, before_u = blanked(nm & (~judge_after | whole), before.angle, before.U95)  # blank (docs)
    out = result_table(layout, table, ids, code,
                       reason_column(verdict_reasons(code, judge_after, edge, noted=unshown), reason),
                       before, after, (before_angle, before_u, after_angle, after_u), placed, surf, d, MIN_SENSORS,
                       no_surface=unmodelled if placed is not None else None)
    full4 = (layout.n == 4) & ~any_col(~before.used) & np.isfinite(before.residual) & np.isfinite(before.angle)
    idx = np.flatnonzero(full4)
    every = len(idx) == N  # every hole charted: the arrays themselves (a gather of every row copies them)
    chart = ChartRows(idx, *(a if every else a[idx] for a in (before.residual, before.noise_sd, before.signature)))
    disagree = (before.disagree | (after.disagree & judge_after if after is not None else False) | poses) & ~unmodelled
    # holes not measured after the adjustment whose before-readings do not rule out a wrong turn of the
    # cell (a hole truly out of tolerance): rule 3's, and those whose before-readings were not sound
    unknown = np.zeros(N, bool)
    if after is not None:
        unknown = nm & judge_after & (poses | ~np.isfinite(before.angle))
        unknown[dup] = False
        unknown &= ~unmodelled  # not in the table, off the edge: not measured for that, not for a gross reading
    spin_free = on_convention = spin_bound = spin_alias = None
    if placed is not None:  # how each judged hole's spin was taken
        spin_free, on_convention = (
            (np.where(judge_after, getattr(after, f), getattr(before, f)) if after is not None else getattr(before, f))
            & ~nm for f in ("spin_free", "convention"))
        # the spin bound's and the alias rule's holes as their reason names them: the before-readings' note stays
        # where the after-readings are judged (these keep the spin from before: on the convention)
        spin_bound = (before.spin_bound | (after.spin_bound & judge_after if after is not None else False)) & ~nm
        spin_alias = (before.alias | (after.alias & judge_after if after is not None else False)) & ~whole
    return HoleBatch(out, code, judged, judged_u, before.angle,
                     after.angle if after is not None else np.full(N, np.nan), chart, disagree, unknown,
                     spin_free, on_convention,
                     *(Labels(*text_codes(out.column(c))) if c in out.column_names else None for c in (CELL, PANEL)),
                     spin_bound=spin_bound, one_sensor=None if placed is not None else edge & ~nm,
                     spin_alias=spin_alias)


def _not_in_table(table, placed, surf, code, reason) -> np.ndarray:
    """Rows whose hole the table does not have, or whose footprint its CAD cannot give: not measured (``code``
    and ``reason`` set), and returned (N,) bool: their readings are not the head's to disagree (rule 2)."""
    table_row = placed.table_row
    unmodelled = table_row < 0
    for i in np.flatnonzero(unmodelled):
        code[i] = CODE[Status.NOT_MEASURED]
        reason[int(i)] = (f"{placed.key} {table.column(placed.key)[int(i)].as_py()!r} is not in the hole table: its "
                          f"local surface is unknown")
    known = np.flatnonzero(table_row >= 0)
    for i in known[surf.problem[table_row[known]] != ""]:  # rare: no Python loop over every hole
        code[i] = CODE[Status.NOT_MEASURED]
        reason[int(i)] = surf.problem[table_row[i]]
        unmodelled[i] = True
    return unmodelled

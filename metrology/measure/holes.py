"""One batch of a hole log measured: per hole the normal, the angle, its U95 and a verdict.

The rules that decide a hole's ``status`` live here, in the order they apply, each with its
threshold and reason:

1. ``NOT_MEASURED``, fewer than :data:`MIN_SENSORS` usable readings: a plane needs 3 points. A
   blank reading, or one outside the sensor's ``range_mm`` (the sensor's own data are not valid
   there), is not used; with 3 left the hole is measured on those 3, with their larger U95.
1b. ``NOT_MEASURED``, with the panel known, a footprint its local surface cannot represent (a tight
   radius: a leading edge, a lip, a tube): a spot where the surface has turned more than
   :data:`MAX_SPOT_TURN_DEG` from the hole's normal (past the crest), or a beam meeting the surface at
   more than :data:`MAX_INCIDENCE_DEG` of incidence (grazing). Both from the fitted surface at the spots
   (:mod:`metrology.measure.remainder`); the hole's readings are not counted as disagreeing (rule 2):
   the model, not the head, is what fails there. (A footprint whose sampled disc leaves the CAD surface,
   past the crest or off the edge, is refused with the panel: :mod:`metrology.panel.holes`.)
2. ``NOT_MEASURED``, the readings disagree (4 sensors): the redundant reading's misfit ``rho``
   exceeds what any panel of radius >= ``min_radius_mm`` can give (``|M|_* / (2 R)``, the
   nuclear norm of the points' second moments weighted by ``q``) by more than
   :data:`GROSS_SIGMAS` of its standard deviation (the reading noise and the calibration's
   uncertainty: a head within its calibration): one reading is gross (a chip, a burr, a spot on
   an edge), or a sensor has moved far beyond its calibration; no normal from these readings can
   be trusted. (A smaller move is the drift watch's.) A hole whose before-readings disagree but
   whose after-readings are sound is judged on the after-readings (the cell turned the wrong way:
   the after-readings measure what it drilled).
2b. Without the panel (4 sensors, a finite ``min_radius_mm``), a misfit beyond :data:`EDGE_SIGMAS` of its
   standard deviation that rule 2's bound explains is the panel's curvature or one sensor's offset (a burr
   under its spot, alike before and after: the cell drills onto the tilt it gives and the after-readings
   confirm it); one redundant reading cannot tell them apart. The pose's U95 then covers both: the tilt of
   the plane through the other three sensors, the farthest over the sensors, plus that plane's own U95
   (:mod:`metrology.measure.onesensor`), so the hole cannot conform on the offset's tilt; the reason of a
   failing or undecided hole says so (:data:`metrology.measure.reasons.EDGE_TEXT`).
3. ``NOT_MEASURED`` after the adjustment, the readings before and after it disagree (4 sensors,
   both poses read on all 4, neither named gross by rule 2): the same spot of the same panel
   gives both misfits, so they differ only by what the panel's curvature does as the head
   tilts, at most
   ``|M_after - M_before|_* / (2 R) + TILT_ALLOWANCE alpha^2 max(|M|_*) / (2 R)`` (``alpha`` the
   larger angle of the two), and by their reading noise (the calibration's errors move both alike and
   cancel): more than :data:`GROSS_SIGMAS` sigmas beyond that, one of the 8 readings is gross. Which one is not identifiable (a gross before-reading,
   the cell turned by it, and a gross after-reading give the same after-readings to first
   order), so the drilled angle is not known: the hole is not measured after the adjustment,
   with that reason, not failed. (A sensor's zero shift moves both misfits alike: the drift
   watch's, not this rule's.)
3b. ``UNDECIDED``, not ``FAILS``, after the adjustment without the panel: the misfits before and after
   differ by more than :data:`CHANGE_SIGMAS` noise sigmas yet within rule 3's allowance (the before-readings
   sound): two gross after-readings whose misfits cancel in part tilt the normal by any angle, so the failure
   is not shown.
4. ISO 14253-1 (conformity with specifications, the supplier's proof): ``CONFORMS`` when
   ``angle + U95 <= tolerance``, ``FAILS`` when ``angle - U95 > tolerance``, ``UNDECIDED``
   otherwise. The angle judged is the drilled hole's: the one measured after the attitude
   adjustment where the log has after-readings, else the one measured before (a log without
   after-readings is taken as drilled as measured).

A hole is judged on its own row alone, so a batch's results do not depend on how the log was
split into batches or partitions (the Dask path relies on it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.core.sym2 import nuclear2
from metrology.io.holelog import CELL, PANEL, text_codes
from metrology.measure.batch import CODE, STATUSES, ChartRows, HoleBatch, Labels, Status, blanked
from metrology.measure.effects import apply_terms
from metrology.measure.normals import hole_normals
from metrology.measure.columns import OUTPUT_COLUMNS, result_table
from metrology.measure.onesensor import one_sensor_u95
from metrology.measure.placement import place
from metrology.measure.reasons import reason_column, verdict_reasons

if TYPE_CHECKING:
    from metrology.measure.panel import HoleSurfaces
    from metrology.measure.placement import Placed
    from metrology.measure.surface import PanelFit

__all__ = ["Status", "STATUSES", "CODE", "Settings", "HoleBatch", "ChartRows", "measure_batch", "MIN_SENSORS", "GROSS_SIGMAS", "OUTPUT_COLUMNS",
           "EDGE_SIGMAS", "CHANGE_SIGMAS",
           "DEFAULT_MIN_RADIUS_MM", "MAX_SPOT_TURN_DEG", "MAX_INCIDENCE_DEG"]

#: fewest readings that give a plane
MIN_SENSORS = 3
#: a redundant misfit beyond the panel's possible shape by this many noise sigmas is a gross reading
#: (two-sided p ~ 2e-9 per hole: about one false flag per 5e8 holes)
GROSS_SIGMAS = 6.0
#: rule 3: a panel seen from a head tilted by alpha has its height's curvature in the TCS changed by
#: up to ``1 / cos(alpha)^3 - 1 ~ 1.5 alpha^2`` and its principal axes turned by alpha: twice that
#: bounds both (checked on the forward simulator's spheres and cylinders of R = 500 mm)
TILT_ALLOWANCE = 3.0
#: rule 2b: a redundant misfit beyond the noise by this many sigmas, within the radius bound, may be one sensor's
#: offset as well as the panel's curvature (a burr under one spot, the same before and after): U95 then covers the
#: tilt the offset would give (:mod:`metrology.measure.onesensor`); rule 2's sigmas: a flat panel's clean holes
#: are left alone (p ~ 2e-9 a hole) (benchmarks/results/gross_issue51_item5.md)
EDGE_SIGMAS = GROSS_SIGMAS
#: rule 3b: misfits before and after that differ by more than this many noise sigmas, within rule 3's allowance,
#: may be two gross after-readings whose misfits cancel in part (which tilt the normal by any angle): such a hole
#: is not shown to fail (two-sided p ~ 0.0027 of a failing hole in control) (benchmarks/results/gross_issue51_item5.md)
CHANGE_SIGMAS = 3.0
#: the smallest panel radius the gross-reading rule allows for (mm): aircraft skins are >= 500 mm
DEFAULT_MIN_RADIUS_MM = 500.0
#: rule 1b: a spot where the surface has turned more than this from the hole's normal is past what the local
#: surface (a height over the tangent plane, to degree 8 over the footprint) holds: on a cylinder a spot past
#: 0.71 R from the crest (benchmarks/results/tight_radii.md)
MAX_SPOT_TURN_DEG = 45.0
#: rule 1b: a beam meeting the surface at more than this incidence grazes it: its spot stretched twice or more,
#: a triangulation sensor's reading there is not the one its calibration made
MAX_INCIDENCE_DEG = 60.0


@dataclass(frozen=True)
class Settings:
    """How holes are judged.

    Attributes
    ----------
    tolerance : float, rad, the perpendicularity tolerance (angle between drill axis and normal)
    min_radius_mm : float, mm, the smallest panel radius the gross-reading rule allows for
    """

    tolerance: float = float(np.radians(0.5))
    min_radius_mm: float = DEFAULT_MIN_RADIUS_MM
    #: each hole's local surface (:class:`metrology.measure.panel.HoleSurfaces`, joined by ``hole_id``):
    #: the normal is fitted with the surface known (:mod:`metrology.measure.surface`), not the micro-plane
    surfaces: "HoleSurfaces | None" = None


@dataclass
class _Measured:
    normal: np.ndarray
    angle: np.ndarray
    U95: np.ndarray
    residual: np.ndarray
    noise_sd: np.ndarray
    signature: np.ndarray
    used: np.ndarray  # (N, n) bool
    reason: dict  # row -> why, the rare holes with a note (metrology.measure.reasons)
    disagree: np.ndarray  # (N,) bool: rule 2, the readings disagree
    residual_sd: np.ndarray  # (N,) float, mm: the misfit's sd (noise and calibration), 4 sensors
    twist: np.ndarray  # (N,) float, mm^2: |M|_*, 4 sensors
    moment: np.ndarray  # (N, 3) float, mm^2: M = sum_i q_i r_i r_i^T as (xx, yy, xy), 4 sensors
    extra: "PanelFit | None" = None  # with the panel known: correction, panel_misfit, panel_misfit_z, turn
    spin_free: np.ndarray | None = None  # (N,) bool, with the panel known: judged with the spin not known
    convention: np.ndarray | None = None  # (N,) bool, with the panel known: the spin in the cell's convention
    spin_bound: np.ndarray | None = None  # (N,) bool, of those: the spin's bound over half U95^2 (measure.spin)
    edge: np.ndarray | None = None  # (N,) bool, rule 2b: U95 covers one sensor's offset


#: rows per call of the per-hole maths (the normals, the misfit's moment): its temporaries stay in
#: the processor's cache (measured: about twice the holes per CPU-second of 262 144-row calls)
CACHE_ROWS = 16384


def _measure(layout: SensorLayout, d, settings: Settings, placed: "Placed | None" = None, effects=None) -> _Measured:
    """Measure every hole of ``d (N, n)`` mm on the sensors that read it in range: on the micro-plane, or with
    ``placed`` (:class:`~metrology.measure.placement.Placed`) each hole's local surface known (rule 2's allowance
    for the panel's shape is then its stated uncertainty, in ``residual_sd``); ``effects`` the layout's head
    terms removed from ``d`` (:class:`~metrology.measure.effects.Applied`): their covariance a source of each
    hole's budget."""
    N, n = d.shape
    lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
    finite = np.isfinite(d)
    in_range = finite & (d >= lo[None]) & (d <= hi[None])
    out = _Measured(np.full((N, 3), np.nan), np.full(N, np.nan), np.full(N, np.nan), np.full(N, np.nan),
                    np.full(N, np.nan), np.full((N, n), np.nan), in_range,
                    {}, np.zeros(N, bool), np.full(N, np.nan), np.full(N, np.nan),
                    np.full((N, 3), np.nan), edge=np.zeros(N, bool))
    if placed is not None:
        from metrology.measure.surface import PanelFit

        out.extra = PanelFit.blank(N)
        out.spin_free, out.convention, out.spin_bound = np.zeros(N, bool), np.zeros(N, bool), np.zeros(N, bool)
    bad = finite & ~in_range
    for i in np.flatnonzero(bad.any(1)):  # rare: name every reading left out
        out.reason[int(i)] = "; ".join(f"{layout.names[j]} = {d[i, j]:.4f} mm outside its range [{lo[j]:g}, {hi[j]:g}] mm"
                                  for j in np.flatnonzero(bad[i]))
    count = in_range.sum(1)
    few = count < MIN_SENSORS
    for i in np.flatnonzero(few):
        blank = [layout.names[j] for j in np.flatnonzero(~finite[i])]
        why = f"{count[i]} usable readings, need {MIN_SENSORS}" + (f" ({', '.join(blank)} blank)" if blank else "")
        prior = out.reason.get(int(i), "")
        out.reason[int(i)] = why + (f"; {prior}" if prior else "")
    # one group per pattern of usable sensors (all, or all but one, in practice)
    code = in_range @ (1 << np.arange(n))
    code[few] = -1
    for p in np.flatnonzero(np.bincount(code[~few], minlength=1 << n)):
        mask = ((p >> np.arange(n)) & 1).astype(bool)
        rows = np.flatnonzero(code == p)
        sub = layout.subset([layout.names[j] for j in np.flatnonzero(mask)]) if not mask.all() else layout
        dd = d[np.ix_(rows, np.flatnonzero(mask))]
        if placed is not None:
            _on_surface(out, rows, mask, sub, dd, placed, settings, effects)
        else:  # in slices of CACHE_ROWS rows, each stored as it comes (its temporaries stay in the cache)
            for i in range(0, len(rows), CACHE_ROWS):
                sl = slice(i, i + CACHE_ROWS)
                h = hole_normals(sub, dd[sl], min_radius_mm=settings.min_radius_mm)
                h = h if effects is None else effects.widen(h, sub, rows[sl], mask)
                _store(out, rows[sl], mask, sub, dd[sl], h, settings, micro=True)
    return out


def _on_surface(out: _Measured, rows, mask, sub, dd, placed, settings: Settings, effects) -> None:
    """The holes ``rows`` read by the sensors ``mask`` (sub-layout ``sub``, readings ``dd``) measured with their
    local surface known (:func:`metrology.measure.spin.panel_normals`), rule 1b and 2 applied, into ``out``."""
    from metrology.measure.spin import SPIN_BOUND_NOTE, panel_normals

    rs = _of(rows)
    j = panel_normals(sub, dd, placed.shape[rs], placed.u_shape[rs], placed.spin[rs],
                      None if placed.higher is None else placed.higher.rows(rs), placed.convention[rs], placed.stated)
    h = j.normals if effects is None else effects.widen(j.normals, sub, rows, mask)
    out.extra.put(rs, j.extra)
    out.spin_free[rs], out.convention[rs], out.spin_bound[rs] = j.free, j.convention, j.bound
    for i in np.flatnonzero(j.free).tolist():  # rare where the log has the pose or the convention holds
        prior = out.reason.get(int(rows[i]))
        out.reason[int(rows[i])] = (prior + "; " if prior else "") + j.free_reason(i)
    for i in np.flatnonzero(j.bound).tolist():  # what such a U95 assumes (measure.spin.SPIN_BOUND_MODEL), said per hole
        prior = out.reason.get(int(rows[i]))
        out.reason[int(rows[i])] = (prior + "; " if prior else "") + SPIN_BOUND_NOTE
    past = past_footprint(j.extra.spot_turn, j.extra.incidence)  # rule 1b
    _store(out, rows, mask, sub, dd, h, settings, micro=False, past=past)
    for i in np.flatnonzero(past).tolist():  # rare: a loop
        r = int(rows[i])
        out.reason[r] = ((out.reason[r] + "; ") if out.reason.get(r) else "") + past_reason(
            j.extra.spot_turn[i], j.extra.incidence[i])
        out.angle[r], out.normal[r], out.U95[r] = np.nan, np.nan, np.nan


def _of(r):
    """The rows ``r``: a slice (views, no gather) where they run on (all sensors read: the usual)."""
    return slice(r[0], r[-1] + 1) if len(r) and r[-1] - r[0] + 1 == len(r) else r


def past_footprint(spot_turn, incidence):
    """(h,) bool, rule 1b: a spot past the crest or a grazing beam (``spot_turn``, ``incidence`` (h,) rad)."""
    with np.errstate(invalid="ignore"):
        return (spot_turn > np.radians(MAX_SPOT_TURN_DEG)) | (incidence > np.radians(MAX_INCIDENCE_DEG))


def past_reason(spot_turn: float, incidence: float) -> str:
    """Rule 1b's reason for one hole (angles in rad)."""
    why = (f"a spot where the surface has turned {np.degrees(spot_turn):.0f} deg from the hole's normal (more than "
           f"{MAX_SPOT_TURN_DEG:g}: past the crest)" if spot_turn > np.radians(MAX_SPOT_TURN_DEG) else
           f"a beam meeting the surface at {np.degrees(incidence):.0f} deg of incidence (more than "
           f"{MAX_INCIDENCE_DEG:g}: grazing)")
    return f"the footprint is past what the panel's local surface represents: {why}"


def _store(out: _Measured, rows, mask, sub, dd, h, settings: Settings, micro: bool, past=None) -> None:
    """Write the holes ``rows`` measured on the sensors ``mask`` (``h``, readings ``dd``) into ``out``, and
    apply rule 2 (the readings disagree) to them."""
    rs = _of(rows)
    out.normal[rs], out.angle[rs], out.U95[rs] = h.normal, h.angle, h.U95
    out.residual[rs] = h.residual
    if h.signature is None:
        return
    out.signature[np.ix_(rows, np.flatnonzero(mask))] = h.signature
    out.noise_sd[rs] = h.residual_noise_sd
    out.residual_sd[rs], out.twist[rs] = h.residual_sd, h.twist
    out.moment[rs] = h.moment if h.moment is not None else np.concatenate(
        [_moment(sub, dd[i:i + CACHE_ROWS]) for i in range(0, len(dd), CACHE_ROWS)])
    # the most any panel of radius >= R gives; with the panel known, what is not known of it
    bound = 0.5 * h.twist / settings.min_radius_mm if h.misfit_bound is None else h.misfit_bound
    gross = np.abs(h.residual) > bound + GROSS_SIGMAS * h.residual_sd
    if past is not None:  # rule 1b's holes: the model, not the head, fails there
        gross &= ~past
    if micro and np.isfinite(settings.min_radius_mm):  # rule 2b: the bound explains a misfit one sensor could make
        with np.errstate(invalid="ignore"):
            edge = ~gross & (np.abs(h.residual) > EDGE_SIGMAS * h.residual_sd)
        if edge.any():
            e = np.flatnonzero(edge)
            out.edge[rows[e]] = True
            out.U95[rows[e]] = one_sensor_u95(sub, dd[e], h.normal[e], h.U95[e])
    if not gross.any():
        return
    out.disagree[rows[gross]] = True
    for i, r in zip(np.flatnonzero(gross), rows[gross]):
        out.reason[int(r)] = (f"readings disagree: the redundant reading misses the plane by "
                              f"{h.residual[i] * 1e3:.1f} µm, more than {GROSS_SIGMAS:g} sigmas beyond what a "
                              f"panel of radius >= {settings.min_radius_mm:g} mm gives (a gross reading)"
                              if micro else
                              f"readings disagree: the redundant reading misses the panel's surface by "
                              f"{h.residual[i] * 1e3:.1f} µm, more than {GROSS_SIGMAS:g} sigmas (a gross reading, "
                              f"or the panel far off its CAD here)")
        out.angle[r] = np.nan  # no normal from these readings
        out.normal[r] = np.nan
        out.U95[r] = np.nan


def _moment(layout, d):
    """(N, 3) float, mm^2: ``M = sum_i q_i r_i r_i^T`` of 4 readings ``d (N, 4)`` as (xx, yy, xy):
    a panel of curvature ``K`` moves the misfit by ``tr(K M) / 2``."""
    from metrology.measure.normals import _null_vector_4

    E, u, dT = layout.zero, layout.direction, d.T
    x, y = E[:, 0, None] + dT * u[:, 0, None], E[:, 1, None] + dT * u[:, 1, None]  # (4, N), mm, TCS: the spots' x, y
    xc, yc = x - x.mean(0), y - y.mean(0)
    q = _null_vector_4(xc, yc)
    return np.stack([(q * xc * xc).sum(0), (q * yc * yc).sum(0), (q * xc * yc).sum(0)], axis=1)


def _nuclear2(m):
    """(N,) the nuclear norm of the symmetric 2 x 2 matrices ``m (N, 3)`` as (xx, yy, xy)."""
    return nuclear2(m[:, 0], m[:, 2], m[:, 1])


def _poses_disagree(before, after, settings):
    """(N,) bool, rule 3: the before- and after-readings' misfits differ by more than the panel's
    curvature can make them as the head tilts, beyond :data:`GROSS_SIGMAS` sigmas; and the
    difference (mm)."""
    R = settings.min_radius_mm
    diff = after.residual - before.residual
    alpha = np.fmax(before.angle, after.angle)
    curve = 0.0 if not np.isfinite(R) else (_nuclear2(after.moment - before.moment)
                                             + TILT_ALLOWANCE * alpha ** 2 * np.fmax(before.twist, after.twist)) / (2 * R)
    sd = np.hypot(before.noise_sd, after.noise_sd)  # noise alone: the calibration's errors move both alike
    sd = np.where(np.isfinite(sd), sd, np.hypot(before.residual_sd, after.residual_sd))
    allowed = curve + GROSS_SIGMAS * sd
    with np.errstate(invalid="ignore"):
        out = np.abs(diff) > allowed
        changed = np.abs(diff) > CHANGE_SIGMAS * sd  # rule 3b
    return out & np.isfinite(allowed) & np.isfinite(diff), diff, changed & np.isfinite(diff)


def _readings(table, names, suffix=""):
    """(N, n) float, mm: the ``d_<sensor><suffix>`` columns, nulls as NaN."""
    cols = [table.column(f"d_{s}{suffix}") for s in names]
    return np.stack([c.to_numpy(zero_copy_only=False).astype(float, copy=False) for c in cols], axis=1)


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
    before = _measure(applied.normals_layout, d, settings, placed, effects=applied)
    if all(f"d_{s}_after" in table.column_names for s in names):
        da = (applied_after := apply_terms(layout, _readings(table, names, "_after"), table, shape=shape)).d
        after = _measure(applied_after.normals_layout, da, settings,
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
        poses, diff, changed = _poses_disagree(before, after, settings)
        poses &= judge_after & ~before.disagree & ~after.disagree  # rule 2 named the gross pose: no doubt left
        changed &= judge_after & ~poses & ~before.disagree & ~after.disagree
        for i in np.flatnonzero(poses).tolist():
            reason[i] = (reason[i] + "; " if reason.get(i) else "") + (
                f"not measured after the adjustment: the misfits before and after it differ by {diff[i] * 1e3:.1f} µm, "
                f"more than {GROSS_SIGMAS:g} sigmas beyond what a panel of radius >= {settings.min_radius_mm:g} mm "
                f"gives as the head tilts: one reading is gross, the drilled angle is not known")
        judged[poses] = np.nan
        judged_u[poses] = np.nan
    code = _verdict(judged, judged_u, settings.tolerance, np.isfinite(before.angle) | judge_after)
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
                       before, after, (before_angle, before_u, after_angle, after_u), placed, surf, d, MIN_SENSORS)
    full4 = (layout.n == 4) & before.used.all(1) & np.isfinite(before.residual) & np.isfinite(before.angle)
    idx = np.flatnonzero(full4)
    chart = ChartRows(idx, before.residual[idx], before.noise_sd[idx], before.signature[idx])
    disagree = (before.disagree | (after.disagree & judge_after if after is not None else False) | poses) & ~unmodelled
    # holes not measured after the adjustment whose before-readings do not rule out a wrong turn of the
    # cell (a hole truly out of tolerance): rule 3's, and those whose before-readings were not sound
    unknown = np.zeros(N, bool)
    if after is not None:
        unknown = nm & judge_after & (poses | ~np.isfinite(before.angle))
        unknown[dup] = False
        unknown &= ~unmodelled  # not in the table, off the edge: not measured for that, not for a gross reading
    spin_free = on_convention = spin_bound = None
    if placed is not None:  # how each judged hole's spin was taken
        spin_free, on_convention, spin_bound = (
            (np.where(judge_after, getattr(after, f), getattr(before, f)) if after is not None else getattr(before, f))
            & ~nm for f in ("spin_free", "convention", "spin_bound"))
    return HoleBatch(out, code, judged, judged_u, before.angle,
                     after.angle if after is not None else np.full(N, np.nan), chart, disagree, unknown,
                     spin_free, on_convention,
                     *(Labels(*text_codes(out.column(c))) if c in out.column_names else None for c in (CELL, PANEL)),
                     spin_bound=spin_bound)


def _verdict(judged, judged_u, tol, sound) -> np.ndarray:
    """(N,) int8, rule 4 (ISO 14253-1) on the angle judged and its U95 (rad; NaN: not measured), rule 1-3's
    holes not measured; ``sound`` (N,) bool, a hole whose readings gave a normal before or after."""
    code = np.full(len(judged), CODE[Status.UNDECIDED], np.int8)
    code[judged + judged_u <= tol] = CODE[Status.CONFORMS]
    code[judged - judged_u > tol] = CODE[Status.FAILS]
    code[~(np.isfinite(judged) & sound)] = CODE[Status.NOT_MEASURED]
    return code


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

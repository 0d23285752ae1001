"""One pose's holes measured (the readings before the attitude adjustment, or after it): each hole's normal, angle
and U95 on the sensors that read it in range, on the micro-plane or with its local surface known, and the rules
of one pose applied to them (rules 1, 1b, 2 and 2b of :mod:`metrology.measure.rules`): :func:`measure_pose`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.measure.normals import hole_normals
from metrology.measure.onesensor import one_sensor_u95
from metrology.measure.rules import EDGE_SIGMAS, GROSS_SIGMAS, MIN_SENSORS, Settings, past_footprint, past_reason

if TYPE_CHECKING:
    from metrology.measure.placement import Placed
    from metrology.measure.surface import PanelFit

__all__ = ["Measured", "measure_pose", "CACHE_ROWS", "patterns", "any_col"]


@dataclass
class Measured:
    """One pose's holes measured (:func:`measure_pose`), by hole."""

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
    alias: np.ndarray | None = None  # (N,) bool, of spin_free: the convention's alias spin (SPIN_ALIAS_SHARE)
    edge: np.ndarray | None = None  # (N,) bool, rule 2b: U95 covers one sensor's offset


#: rows per call of the per-hole maths (the normals, the misfit's moment): its temporaries stay in
#: the processor's cache (measured: about twice the holes per CPU-second of 262 144-row calls)
CACHE_ROWS = 16384


def measure_pose(layout: SensorLayout, d, settings: Settings, placed: "Placed | None" = None, effects=None) -> Measured:
    """Measure every hole of ``d (N, n)`` mm on the sensors that read it in range: on the micro-plane, or with
    ``placed`` (:class:`~metrology.measure.placement.Placed`) each hole's local surface known (rule 2's allowance
    for the panel's shape is then its stated uncertainty, in ``residual_sd``); ``effects`` the layout's head
    terms removed from ``d`` (:class:`~metrology.measure.effects.Applied`): their covariance a source of each
    hole's budget."""
    N, n = d.shape
    lo, hi = layout.range_mm[:, 0], layout.range_mm[:, 1]
    finite = np.isfinite(d)
    in_range = (d >= lo[None]) & (d <= hi[None])  # a blank (NaN) compares False
    out = Measured(np.full((N, 3), np.nan), np.full(N, np.nan), np.full(N, np.nan), np.full(N, np.nan),
                    np.full(N, np.nan), np.full((N, n), np.nan), in_range,
                    {}, np.zeros(N, bool), np.full(N, np.nan), np.full(N, np.nan),
                    np.full((N, 3), np.nan), edge=np.zeros(N, bool))
    if placed is not None:
        from metrology.measure.surface import PanelFit

        out.extra = PanelFit.blank(N)
        out.spin_free, out.convention, out.spin_bound, out.alias = (np.zeros(N, bool) for _ in range(4))
    bad = finite & ~in_range
    for i in np.flatnonzero(any_col(bad)):  # rare: name every reading left out
        out.reason[int(i)] = "; ".join(f"{layout.names[j]} = {d[i, j]:.4f} mm outside its range [{lo[j]:g}, {hi[j]:g}] mm"
                                  for j in np.flatnonzero(bad[i]))
    code = patterns(in_range)  # each hole's pattern of usable sensors
    count = np.array([bin(p).count("1") for p in range(1 << n)])[code]
    few = count < MIN_SENSORS
    for i in np.flatnonzero(few):
        blank = [layout.names[j] for j in np.flatnonzero(~finite[i])]
        why = f"{count[i]} usable readings, need {MIN_SENSORS}" + (f" ({', '.join(blank)} blank)" if blank else "")
        prior = out.reason.get(int(i), "")
        out.reason[int(i)] = why + (f"; {prior}" if prior else "")
    # one group per pattern of usable sensors (all, or all but one, in practice)
    code[few] = -1
    for p in np.flatnonzero(np.bincount(code[~few], minlength=1 << n)):
        mask = ((p >> np.arange(n)) & 1).astype(bool)
        rows = np.flatnonzero(code == p)
        sub = layout.subset([layout.names[j] for j in np.flatnonzero(mask)]) if not mask.all() else layout
        dd = d if mask.all() and len(rows) == N else d[np.ix_(rows, np.flatnonzero(mask))]  # every hole read whole: d
        if placed is not None:
            _on_surface(out, rows, mask, sub, dd, placed, settings, effects)
        else:  # in slices of CACHE_ROWS rows, each stored as it comes (its temporaries stay in the cache)
            for i in range(0, len(rows), CACHE_ROWS):
                sl = slice(i, i + CACHE_ROWS)
                h = hole_normals(sub, dd[sl], min_radius_mm=settings.min_radius_mm)
                h = h if effects is None else effects.widen(h, sub, rows[sl], mask)
                _store(out, rows[sl], mask, sub, dd[sl], h, settings, micro=True)
    return out


def _on_surface(out: Measured, rows, mask, sub, dd, placed, settings: Settings, effects) -> None:
    """The holes ``rows`` read by the sensors ``mask`` (sub-layout ``sub``, readings ``dd``) measured with their
    local surface known (:func:`metrology.measure.spin.panel_normals`), rule 1b and 2 applied, into ``out``."""
    from metrology.measure.spin import SPIN_BOUND_NOTE, panel_normals

    rs = _of(rows)
    j = panel_normals(sub, dd, placed.shape[rs], placed.u_shape[rs], placed.spin[rs],
                      None if placed.higher is None else placed.higher.rows(rs), placed.convention[rs], placed.stated)
    h = j.normals if effects is None else effects.widen(j.normals, sub, rows, mask)
    out.extra.put(rs, j.extra)
    out.spin_free[rs], out.convention[rs], out.spin_bound[rs] = j.free, j.convention, j.bound
    out.alias[rs] = np.isfinite(j.alias)
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


def _store(out: Measured, rows, mask, sub, dd, h, settings: Settings, micro: bool, past=None) -> None:
    """Write the holes ``rows`` measured on the sensors ``mask`` (``h``, readings ``dd``) into ``out``, and
    apply rule 2 (the readings disagree) to them."""
    rs = _of(rows)
    out.normal[rs], out.angle[rs], out.U95[rs] = h.normal, h.angle, h.U95
    out.residual[rs] = h.residual
    if h.signature is None:
        return
    out.signature[(rs, slice(None)) if mask.all() else np.ix_(rows, np.flatnonzero(mask))] = h.signature
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


def patterns(m):
    """(N,) int64, each row's pattern of ``m`` (N, n) bool as bits (sensor ``j`` bit ``j``), by its columns (``m @ (1 <<
    arange(n))``: a product of booleans is no BLAS product, and costs ten times)."""
    out = m[:, 0].astype(np.int64)
    for j in range(1, m.shape[1]):
        out |= m[:, j].astype(np.int64) << j
    return out


def any_col(m):
    """(N,) bool, ``m.any(1)`` of ``m`` (N, n) bool by its columns (a reduction along a short row costs ten times)."""
    out = m[:, 0].copy()
    for j in range(1, m.shape[1]):
        out |= m[:, j]
    return out

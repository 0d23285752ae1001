"""Drift watch: a two-sided CUSUM chart on each hole's redundant-reading residual.

On a 4-sensor head every hole carries one redundant reading: its misfit ``rho`` to the micro-plane
(:mod:`metrology.measure.normals`). While every sensor holds its calibration, ``rho`` scatters
about a level set by the calibration's small errors and the panel's shape; when one sensor's
zero moves by ``delta``, ``rho`` moves by ``q_k (m.u_k) delta``. The chart:

1. **Baseline** (phase I): the first :data:`BASELINE_HOLES` holes of each cell give the
   in-control level (median) and scale: the standard deviation of the holes within 5 MAD of the
   median, raised to its upper 95 % confidence bound (``1 + 1.645 / sqrt(2 (n - 1))``: a scale
   estimated low would shorten the in-control run length a lot, one estimated high lengthens the
   time to detect a little), and never below the reading noise's own sigma of ``rho``. The
   residual's spread is more than the noise's: the calibration's small errors move ``rho`` with
   the hole's geometry. The baseline's holes are not charted. The chart runs on across panels, so a drift slower than a
   panel is seen; with ``by_panel`` each panel takes a new baseline instead (for panels whose
   shape moves the residual's level: a twist under the foot), which cannot see a change that
   coincides with a new panel, nor a drift slower than a panel.
2. **Chart** (phase II): ``x_t = (rho_t - level) / scale`` into the two-sided CUSUM

       S+_t = max(0, S+_{t-1} + x_t - k),   S-_t = max(0, S-_{t-1} - x_t - k),

   with reference value ``k`` = :data:`CUSUM_K` (tuned to a shift of ``2 k`` = 1 scale) and an
   alarm when either sum exceeds ``h``. ``h`` is chosen so that the in-control average run length
   (ARL, holes between false alarms with ``x ~ N(0, 1)``) is :data:`ARL0_HOLES`, computed by the
   Markov-chain method of Brook and Evans (1972) (:func:`cusum_arl`). ``x`` is clipped at
   +-:data:`CLIP` first, so one gross reading cannot raise an alarm on its own.
3. **Alarm**: the time and hole of the alarm, the hole where the change began (the last hole at
   which the alarming sum was zero: Page's estimate), and says "recalibrate". The chart then takes
   a new baseline (one alarm per change), and the change's size is the new level minus the old
   one (µm; when the log ends first, the level of the holes it has), with what it means at each
   sensor: a zero shift of ``size / signature_k``. One redundant reading cannot tell which of the
   4 sensors moved; the alarm lists all four with their sizes. The alarm also gives the run the
   chart saw (``run_um``: the residual's mean from the change's start to the alarm, less the old
   level: what the plotted sum climbed on) and whether the change **persisted**: the new level
   differs from the old by more than :data:`PERSIST_Z` standard errors of the two medians. A run
   that did not persist (a false alarm, at the rate the ARL states, or a transient knock) is sized
   near 0 by the levels although the chart climbed on a run of ``run_um``; its advice is to check
   the head, not to recalibrate.

The state is a small object, so the chart runs over a log of any length in bounded memory, and
over a fleet's partitions in time order (:meth:`CusumChart.update` on one batch after another).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from metrology.core.stats import robust_sigma
from metrology.measure.series import Bins, extremes, merge_pairs

__all__ = ["CUSUM_K", "CUSUM_H", "ARL0_HOLES", "ARL_AT_DETECTABLE", "BASELINE_HOLES", "CLIP", "PERSIST_Z", "cusum_h", "cusum_arl", "Alarm", "PendingAlarm", "CusumChart",
           "chart_settings"]

#: reference value of the CUSUM, in scales: the chart is tuned to a shift of 2 k = 1 scale
CUSUM_K = 0.5
#: in-control average run length, holes: about one false alarm per million holes per cell
ARL0_HOLES = 1_000_000
#: holes of each cell (each panel with ``by_panel``) that set the chart's level and scale
BASELINE_HOLES = 1000
#: standardized residuals are clipped to +-CLIP before the CUSUM (a gross reading adds at most this)
CLIP = 4.0
#: the decision interval, scales: ``cusum_h(ARL0_HOLES, CUSUM_K)`` (tests/measure/test_chart.py
#: checks it), fixed here so a run does not solve for it
CUSUM_H = 12.667
#: a change is "detectable" at this shift of the residual, in scales: the CUSUM's ARL there is
#: tens of holes (cusum_arl(h, k, DETECTABLE_SCALES))
DETECTABLE_SCALES = 1.0
#: ``cusum_arl(CUSUM_H, CUSUM_K, DETECTABLE_SCALES)``, holes (checked by the tests)
ARL_AT_DETECTABLE = 25.7
#: an alarm's change persisted when the new level minus the old exceeds this many standard errors of
#: that difference (each level a median of ``n`` holes: ``sqrt(pi / 2) scale / sqrt(n)``); 3: a false
#: alarm passes it in 0.3 % of cases, a change of one detectable size (1 scale) on 1000-hole baselines
#: is 18 standard errors
PERSIST_Z = 3.0


def _arl_one_sided(h, k, shift, n_states=100):
    """ARL of the upper CUSUM ``S = max(0, S + x - k)``, ``x ~ N(shift, 1)``, alarm at ``S > h``
    (Brook-Evans Markov chain on ``n_states`` cells of ``[0, h]``)."""
    from scipy.stats import norm

    w = h / n_states
    centres = (np.arange(n_states) + 0.5) * w
    centres[0] = 0.0  # state 0 is the atom at S = 0
    # transition from state i to j: S' = S_i + x - k in cell j
    lo = np.arange(n_states) * w
    hi = lo + w
    lo[0] = -np.inf
    base = centres[:, None] - k + shift
    P = norm.cdf(hi[None, :] - base) - norm.cdf(lo[None, :] - base)
    arl = np.linalg.solve(np.eye(n_states) - P, np.ones(n_states))
    return float(arl[0])


def cusum_arl(h: float, k: float = CUSUM_K, shift: float = 0.0) -> float:
    """ARL (holes) of the two-sided CUSUM at a mean shift ``shift`` (scales): ``1 / (1/ARL+ + 1/ARL-)``."""
    up, down = _arl_one_sided(h, k, shift), _arl_one_sided(h, k, -shift)
    return 1.0 / (1.0 / up + 1.0 / down)


@lru_cache(maxsize=8)
def cusum_h(arl0: float = ARL0_HOLES, k: float = CUSUM_K) -> float:
    """The decision interval ``h`` whose in-control two-sided ARL is ``arl0`` holes (bisection)."""
    lo, hi = 1.0, 30.0
    for _ in range(30):  # to 3e-8 of h
        mid = 0.5 * (lo + hi)
        if cusum_arl(mid, k) < arl0:
            lo = mid
        else:
            hi = mid
    return hi


def chart_settings() -> dict:
    """The chart's figures: ``h``, the in-control ARL and the ARL at the detectable shift."""
    return {"k": CUSUM_K, "h": CUSUM_H, "arl0_holes": ARL0_HOLES, "baseline_holes": BASELINE_HOLES,
            "detectable_scales": DETECTABLE_SCALES, "arl_at_detectable_holes": ARL_AT_DETECTABLE}


@dataclass(frozen=True)
class Alarm:
    """A drift alarm of one cell.

    Attributes
    ----------
    cell : str
    hole_id : str, the hole at which the chart alarmed; time_s : float, s since the epoch
    start_hole_id : str, where the change began (the last hole with the alarming sum at zero);
        start_time_s : float, s
    holes_since_start : int
    size_um : float, µm, the change of the redundant residual since ``start`` (signed): the new level
        minus the old
    sensor_shift_um : dict, sensor -> µm: the zero shift of that sensor alone that explains it
    direction : str, "up" or "down"
    panel : str
    run_um : float, µm, the residual's mean over the alarm's run (``start`` to the alarm) less the old
        level: what the chart climbed on
    persisted : bool, the change held after the alarm (``|size| > PERSIST_Z`` standard errors); False: a
        run that did not persist (a false alarm or a transient), ``size_um`` near 0
    """

    cell: str
    panel: str
    hole_id: str
    time_s: float
    start_hole_id: str
    start_time_s: float
    holes_since_start: int
    size_um: float
    sensor_shift_um: dict
    direction: str
    run_um: float = float("nan")
    persisted: bool = True

    @property
    def advice(self) -> str:
        if self.persisted:
            return "recalibrate"
        return "check the head: the run did not persist (a false alarm or a transient knock)"

    def to_dict(self) -> dict:
        return {"cell": self.cell, "panel": self.panel, "hole_id": self.hole_id, "time_s": self.time_s,
                "start_hole_id": self.start_hole_id, "start_time_s": self.start_time_s,
                "holes_since_start": self.holes_since_start, "size_um": self.size_um,
                "sensor_shift_um": dict(self.sensor_shift_um), "direction": self.direction,
                "run_um": self.run_um, "persisted": self.persisted, "advice": self.advice}


@dataclass(frozen=True)
class PendingAlarm:
    """An alarm raised and waiting for the new baseline that sizes its change (:meth:`CusumChart._size_pending`).

    Attributes
    ----------
    level : float, mm, the chart's level before the change
    signature : (4,) float, mm per mm, the baseline's signature before the change
    scale : float, mm, the chart's scale (sizes the level change's standard error, :data:`PERSIST_Z`)
    level_holes : int, the holes the level before the change was taken on
    run_mm : float, mm, the mean of the run the chart climbed on (the change's size when the log ends
        before a new level)
    raised : dict, the alarm as raised: cell, panel, hole_id, time_s, start_hole_id, start_time_s,
        holes_since_start, direction (:class:`Alarm`'s fields but its size)
    """

    level: float
    signature: np.ndarray
    scale: float
    level_holes: int
    run_mm: float
    raised: dict


@dataclass
class _Run:
    """Where one one-sided sum was last zero, and the residuals summed since then."""

    hole_id: str = ""
    time_s: float = 0.0
    index: int = 0
    total: float = 0.0
    count: int = 0


@dataclass
class CusumChart:
    """The drift chart of one cell: feed it the cell's 4-sensor holes in time order (:meth:`update`).

    Attributes
    ----------
    cell : str
    sensors : tuple of str
    h : float, the decision interval (scales); k : float, the reference value (scales)
    alarms : list of Alarm
    series : list of (time_s, statistic) pairs for the plot, in time order: the larger of the two
        sums, thinned to at most about ``2 keep`` points by keeping each bin's minimum and maximum
        (:meth:`_record`), so every peak, the alarm's crossing of ``h`` and every return to zero
        stay drawn; a pair ``(time_s, nan)`` breaks the line where the chart took a new baseline
        (after an alarm, or at a new panel with ``by_panel``): its baseline's holes are not charted
    charted : int, holes charted so far (the baselines' holes excluded)
    """

    cell: str
    sensors: tuple
    h: float = CUSUM_H
    k: float = CUSUM_K
    baseline_holes: int = BASELINE_HOLES
    keep: int = 2000
    alarms: list = field(default_factory=list)
    charted: int = 0
    by_panel: bool = False
    panel: str | None = None
    _segment: str | None = None
    level: float = float("nan")
    scale: float = float("nan")
    level_holes: int = 0  # holes whose median is ``level``
    signature: np.ndarray | None = None
    _base: list = field(default_factory=list)
    _s: list = field(default_factory=lambda: [0.0, 0.0])  # the upper and lower sums
    _runs: list = field(default_factory=lambda: [_Run(), _Run()])
    _stride: int = 1  # holes per bin of the plotted series
    _bins: "Bins" = field(default_factory=lambda: Bins())  # the plotted series' bins and breaks
    _pending: PendingAlarm | None = None  # an alarm waiting for the new baseline to size the change

    def _restart(self, segment) -> None:
        self.finish()
        self._bins.brk()  # the line breaks over the new baseline's holes
        self._segment = segment
        self._base = []
        self.level = self.scale = float("nan")
        self.level_holes = 0
        self.signature = None
        self._s = [0.0, 0.0]
        self._runs = [_Run(), _Run()]

    def update(self, hole_id, time_s, panel, rho_mm, noise_sd_mm, signature) -> None:
        """Feed one batch of holes, in time order.

        Parameters
        ----------
        hole_id : (N,) str (an array or a pyarrow StringArray); time_s : (N,) float, s; panel : (N,) str
        rho_mm : (N,) float, mm, the redundant residual
        noise_sd_mm : (N,) float, mm, its sigma from the reading noise
        signature : (N, 4) float, ``d rho / d delta_k`` (mm per mm)
        """
        panel = panel if isinstance(panel, np.ndarray) and panel.dtype.kind == "U" else np.asarray(panel).astype(str)
        seg = panel if self.by_panel else np.zeros(len(panel), dtype="<U1")
        N = len(rho_mm)
        i = 0
        while i < N:
            if seg[i] != self._segment:
                self._restart(seg[i])
            other = np.flatnonzero(seg[i:] != seg[i])
            j = i + (int(other[0]) if other.size else N - i)
            self.panel = str(panel[j - 1])
            if np.isnan(self.level):
                take = min(self.baseline_holes - sum(len(b[0]) for b in self._base), j - i)
                self._base.append((rho_mm[i:i + take], noise_sd_mm[i:i + take], signature[i:i + take]))
                i += take
                if sum(len(b[0]) for b in self._base) >= self.baseline_holes:
                    self._set_baseline()
                continue
            at = self._chart(hole_id[i:j], time_s[i:j], rho_mm[i:j], panel[i:j])
            i = j if at is None else i + at + 1

    def _set_baseline(self) -> None:
        rho = np.concatenate([b[0] for b in self._base])
        sd = np.concatenate([b[1] for b in self._base])
        self.level = float(np.median(rho))
        self.level_holes = len(rho)
        mad = robust_sigma(rho, about=self.level)
        kept = rho[np.abs(rho - self.level) <= 5.0 * max(mad, 1e-12)]
        sdev = float(np.std(kept, ddof=1)) if len(kept) > 1 else mad
        self.scale = max(sdev * (1.0 + 1.645 / np.sqrt(2.0 * max(len(kept) - 1, 1))), float(np.median(sd)))
        self.signature = np.median(np.concatenate([b[2] for b in self._base]), axis=0)
        self._base = []
        self._size_pending()

    @property
    def pending(self) -> PendingAlarm | None:
        """The alarm raised and not yet sized (its new baseline not complete), or None."""
        return self._pending

    def _size_pending(self) -> None:
        """Size the pending alarm's change as the new level minus the old, and file the alarm."""
        if self._pending is None:
            return
        p, self._pending = self._pending, None
        persisted = True
        if np.isfinite(self.level):
            size_mm = self.level - p.level
            se = np.sqrt(np.pi / 2) * p.scale * np.sqrt(1.0 / p.level_holes + 1.0 / max(self.level_holes, 1))
            persisted = bool(abs(size_mm) > PERSIST_Z * se)
        else:  # the log ended at the alarm: the run is all there is
            size_mm = p.run_mm
        sig = self.signature if self.signature is not None else p.signature
        shifts = {s: float(size_mm / g * 1e3) for s, g in zip(self.sensors, sig)}
        self.alarms.append(Alarm(**p.raised, size_um=float(size_mm * 1e3), sensor_shift_um=shifts,
                                 run_um=float(p.run_mm * 1e3), persisted=persisted))

    def finish(self) -> None:
        """End of the log: size a pending alarm on the holes taken since (or on the alarm's window)."""
        if self._pending is not None and self._base and np.isnan(self.level):
            rho = np.concatenate([b[0] for b in self._base])
            self.level = float(np.median(rho))
            self.level_holes = len(rho)
            self.signature = np.median(np.concatenate([b[2] for b in self._base]), axis=0)
            self._base = []
        self._size_pending()

    def _chart(self, hole_id, time_s, rho, panel):
        """Chart the holes of one panel run; the index of the alarming hole, or None."""
        raw = (np.asarray(rho, float) - self.level) / self.scale
        x = np.clip(raw, -CLIP, CLIP)
        sums, first = [], len(x)
        for side, y in enumerate((x - self.k, -x - self.k)):
            C = np.cumsum(y)
            M = np.minimum.accumulate(np.concatenate([[-self._s[side]], C]))[1:]
            S = C - M
            sums.append(S)
            over = np.flatnonzero(S > self.h)
            if over.size:
                first = min(first, int(over[0]))
        end = first + 1 if first < len(x) else len(x)
        for side in range(2):
            self._advance(side, sums[side][:end], raw[:end], hole_id, time_s)
        self._record(time_s[:end], np.maximum(sums[0][:end], sums[1][:end]))
        self.charted += end
        if first == len(x):
            return None
        up = sums[0][first] > self.h
        run = self._runs[0 if up else 1]
        pending = PendingAlarm(self.level, self.signature, self.scale, self.level_holes,
                               run.total / max(run.count, 1) * self.scale,
                               dict(cell=self.cell, panel=str(panel[first]), hole_id=str(hole_id[first]),
                                    time_s=float(time_s[first]), start_hole_id=run.hole_id, start_time_s=run.time_s,
                                    holes_since_start=self.charted - run.index, direction="up" if up else "down"))
        self._restart(self._segment)  # a new baseline: one alarm per change, sized by the new level
        self._pending = pending
        return first

    def _advance(self, side, S, x, hole_id, time_s):
        """Carry one sum's state over the charted holes ``S (m,)``: the last zero and the sum of the
        (unclipped) residuals ``x`` since, which sizes the change."""
        run = self._runs[side]
        zeros = np.flatnonzero(S == 0.0)
        if zeros.size:
            z = int(zeros[-1])
            nxt = z + 1
            if nxt < len(S):
                run.hole_id, run.time_s, run.index = str(hole_id[nxt]), float(time_s[nxt]), self.charted + nxt
            else:
                run.hole_id, run.time_s, run.index = "", 0.0, self.charted + nxt
            run.total, run.count = float(x[nxt:].sum()), len(S) - nxt
        else:
            if run.count == 0 and len(S):
                run.hole_id, run.time_s, run.index = str(hole_id[0]), float(time_s[0]), self.charted
            run.total += float(x.sum())
            run.count += len(S)
        if len(S):
            self._s[side] = float(S[-1])

    def _record(self, t, stat) -> None:
        """Add charted holes to the plotted series: bins of ``_stride`` holes, each kept as its
        first, minimum, maximum and last point (:func:`metrology.measure.series.extremes`); when there are more than
        ``keep`` bins, neighbours within a run between breaks are merged pairwise and the stride
        doubles. A bounded series that still shows every extreme: decimating it would
        drop the peaks, the alarm among them."""
        t = np.asarray(t, float)
        stat = np.asarray(stat, float)
        w = self._stride
        # a long call binned at once at the stride the merges below would reach (a first batch at stride 1 was
        # 2.6e5 bins merged eight times over): the same bins while the line's current run holds an even number
        # of bins, the new ones then pairing among themselves as the merges would pair them
        while len(stat) >= 2 * w and self._bins.count + -(-len(stat) // w) > self.keep and self._bins.run % 2 == 0:
            if self._bins.count:
                self._bins = merge_pairs(self._bins)
            w *= 2
        self._stride = w
        full = len(stat) // w * w
        self._bins.add(*extremes(t[:full].reshape(-1, w), stat[:full].reshape(-1, w)))
        if full < len(stat):
            self._bins.add(*extremes(t[full:][None, :], stat[full:][None, :]))
        while self._bins.count > self.keep:
            self._bins = merge_pairs(self._bins)
            self._stride *= 2

    @property
    def series(self) -> list:
        out = []
        b = self._bins
        for t, s, v, brk in zip(b.t.tolist(), b.s.tolist(), b.v.tolist(), b.br.tolist()):
            if brk:
                out.append((out[-1][0], float("nan")))
            else:
                out.extend((ti, si) for ti, si, vi in zip(t, s, v) if vi)
        return out

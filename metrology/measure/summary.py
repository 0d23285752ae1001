"""The fleet summary: per cell, panel and day, counts by status, perpendicularity quantiles and
the capability Ppk; mergeable, so a summary of partitions measured apart (Dask) equals the one measured in
one pass.

Quantiles come from a histogram of the angle on :data:`EDGES_DEG` (geometric bins, 1.7 % wide):
a quantile is the geometric middle of its bin, within 0.9 % of the exact one.

Capability: the judged angle is bounded below by 0 (the length of a 2-D tilt: a folded, skewed
distribution), so a normal-theory Cpk ``(tol - mean) / (3 s)`` describes no tail of it. metro
gives the ISO 22514-2 percentile-based performance index against the one upper limit (the
tolerance), ``Ppk = (tol - X50) / (X99.865 - X50)``, on the judged angle's histogram, with a 95 %
percentile-bootstrap interval (:data:`BOOTSTRAP` multinomial resamplings of the histogram, a
numpy Generator seeded with :data:`BOOTSTRAP_SEED`: same data, same interval). It needs at least
:data:`MIN_PPK_HOLES` holes (else NaN): the 99.865th percentile of fewer holes is their largest.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from metrology.io.arrays import to_numpy
from metrology.io.holelog_schema import CELL, PANEL, TIME_S, text_codes
from metrology.measure.holes import CODE, STATUSES, HoleBatch, Status
from metrology.measure.tally import (CAD_OFFSET_MM, OFF_CAD_SIGMAS, CadSums, Counts, Figures, GroupKey, OffCadSums,
                                     Quantiles, WorstHole)

__all__ = ["FleetSummary", "Group", "GroupKey", "Counts", "Quantiles", "Figures", "WorstHole", "OffCadSums", "CadSums",
           "EDGES_DEG", "WORST"]

#: histogram edges of the angle, deg: 1e-4 to 90 deg in geometric steps (and 0 below)
EDGES_DEG = np.concatenate([[0.0], np.geomspace(1e-4, 90.0, 801)])
#: the worst holes kept for the report
WORST = 20
_STATUSES = tuple(str(s) for s in STATUSES)  # the codes' order (holes.CODE)
#: Ppk's percentiles (ISO 22514-2: the median and the upper 0.135 % point, a normal's +3 sigma)
PPK_Q = (0.5, 0.99865)
#: fewest holes for a Ppk: 1 / (1 - 0.99865) = 741 holes put one beyond X99.865; 1000 keep a few there
MIN_PPK_HOLES = 1000
#: bootstrap resamplings of the histogram for Ppk's 95 % interval, and the Generator's seed
BOOTSTRAP = 400
BOOTSTRAP_SEED = 20261126
CAPABILITY = ("Ppk, ISO 22514-2 percentile method, one-sided upper: (tolerance - X50) / (X99.865 - X50) of the "
              "judged angle (bounded below by 0, not normal); 95 % interval: percentile bootstrap")


@dataclass
class Group:
    """Holes counted together: by status, and the judged angle's moments (deg); with ``hists``
    the angle's histograms before and after the adjustment (on :data:`EDGES_DEG`). A group of a
    cell, panel and day keeps no histogram (a fleet drills many panels on many days: 13 kB a
    group would grow with the log); a cell, and the fleet, keep one."""

    counts: np.ndarray = field(default_factory=lambda: np.zeros(len(_STATUSES), np.int64))
    n: int = 0
    total: float = 0.0
    total_sq: float = 0.0
    hist_before: np.ndarray | None = None
    hist_after: np.ndarray | None = None
    hist_judged: np.ndarray | None = None

    def merge(self, other: "Group") -> None:
        self.counts += other.counts
        self.n += other.n
        self.total += other.total
        self.total_sq += other.total_sq
        if other.hist_before is not None:
            if self.hist_before is None:
                self.hist_before = np.zeros(len(EDGES_DEG), np.int64)
                self.hist_after = np.zeros(len(EDGES_DEG), np.int64)
                self.hist_judged = np.zeros(len(EDGES_DEG), np.int64)
            self.hist_before += other.hist_before
            self.hist_after += other.hist_after
            self.hist_judged += other.hist_judged


#: the geometric edges' logarithms: a bin found from the angle's logarithm, then checked against the edges
_LOG_FIRST, _LOG_STEP = np.log(EDGES_DEG[1]), np.log(EDGES_DEG[-1] / EDGES_DEG[1]) / (len(EDGES_DEG) - 2)


def _bins(angle_deg):
    """Histogram bin of each finite angle >= 0 (the last bin takes everything above 90 deg): the ``i`` with
    ``EDGES_DEG[i] <= angle < EDGES_DEG[i + 1]``, as a search of the edges finds it (its logarithm gives the bin
    to a rounding error; the edges themselves settle it: a search cost 0.15 s per million holes)."""
    last = len(EDGES_DEG) - 1
    with np.errstate(divide="ignore"):
        guess = np.clip(np.floor((np.log(angle_deg) - _LOG_FIRST) / _LOG_STEP) + 1, 0, last).astype(np.int64)
    guess -= angle_deg < EDGES_DEG[guess]
    up = np.minimum(guess + 1, last)
    guess += (guess < last) & (angle_deg >= EDGES_DEG[up])
    return guess


def _unique(code):
    """``numpy.unique(code, return_inverse=True)`` of ``code`` (N,) int64; by a count of each value where they span
    a range not much longer than ``code`` (a batch's groups: a few cells, panels and days), which a sort of a million
    codes cost ten times."""
    if not len(code):
        return np.unique(code, return_inverse=True)
    lo = int(code.min())
    span = int(code.max()) - lo + 1
    if span > 4 * len(code) + 64:
        return np.unique(code, return_inverse=True)
    present = np.bincount(code - lo, minlength=span) > 0
    return np.flatnonzero(present) + lo, (np.cumsum(present) - 1)[code - lo]


def _groups(batch):
    """Each row's group (N,) int and the groups' keys (:class:`GroupKey`)."""
    import datetime as dt

    t = batch.columns
    ci, cells = (batch.cell.codes, batch.cell.values) if batch.cell is not None else text_codes(t.column(CELL))
    pi, panels = (batch.panel.codes, batch.panel.values) if batch.panel is not None else text_codes(t.column(PANEL))
    day = np.floor(to_numpy(t.column(TIME_S)) / 86400.0).astype(np.int64)
    d0 = int(day.min()) if len(day) else 0
    nd = int(day.max()) - d0 + 1 if len(day) else 1
    code = (ci * len(panels) + pi) * nd + (day - d0)
    uniq, g = _unique(code)
    keys = []
    for c in uniq:
        cp, dd = divmod(int(c), nd)
        ck, pk = divmod(cp, len(panels))
        keys.append(GroupKey(cells[ck], panels[pk], (dt.date(1970, 1, 1) + dt.timedelta(days=d0 + dd)).isoformat()))
    return g.reshape(-1), keys


def quantile_deg(hist, q):
    """The ``q`` quantile (deg) of a histogram on :data:`EDGES_DEG`; NaN when empty."""
    total = 0 if hist is None else hist.sum()
    if hist is None or total == 0:
        return float("nan")
    return float(_bin_quantiles(np.asarray(hist)[None], q)[0])


def _bin_quantiles(hists, q):
    """(B,) the ``q`` quantile (deg) of each histogram ``hists (B, len(EDGES_DEG))``, none empty."""
    cum = np.cumsum(hists, axis=1)
    k = (cum < q * cum[:, -1:]).sum(1)
    lo = EDGES_DEG[k]
    hi = EDGES_DEG[np.minimum(k + 1, len(EDGES_DEG) - 1)]
    return np.where(lo > 0, np.sqrt(lo * hi), hi / 2)


def _interpolated_quantiles(hists, q):
    """(B,) the ``q`` quantile (deg) of each histogram ``hists (B, len(EDGES_DEG))``, none empty,
    interpolated within its bin (geometrically; linearly in the first bin, from 0): smooth in the
    counts, so the bootstrap's interval is not the bins' steps."""
    cum = np.cumsum(hists, axis=1)
    target = q * cum[:, -1]
    k = (cum < target[:, None]).sum(1)
    rows = np.arange(len(hists))
    below = np.where(k > 0, cum[rows, np.maximum(k - 1, 0)], 0)
    frac = np.clip((target - below) / np.maximum(hists[rows, k], 1), 0.0, 1.0)
    lo = EDGES_DEG[k]
    hi = EDGES_DEG[np.minimum(k + 1, len(EDGES_DEG) - 1)]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(lo > 0, lo * (hi / np.where(lo > 0, lo, 1.0)) ** frac, hi * frac)


def ppk(hist, tolerance_deg):
    """The percentile-based Ppk of a histogram on :data:`EDGES_DEG` against the upper limit
    ``tolerance_deg`` and its 95 % bootstrap interval: ``(ppk, (lo, hi))``, NaN with fewer than
    :data:`MIN_PPK_HOLES` holes (module docstring)."""
    nan = float("nan")
    n = 0 if hist is None else int(hist.sum())
    if n < MIN_PPK_HOLES:
        return nan, (nan, nan)

    def index(h):
        x50, x99 = _interpolated_quantiles(h, PPK_Q[0]), _interpolated_quantiles(h, PPK_Q[1])
        with np.errstate(divide="ignore", invalid="ignore"):
            return (tolerance_deg - x50) / (x99 - x50)

    rng = np.random.default_rng(BOOTSTRAP_SEED)
    draws = index(rng.multinomial(n, hist / n, size=BOOTSTRAP))
    lo, hi = np.quantile(draws, [0.025, 0.975])
    return float(index(np.asarray(hist)[None])[0]), (float(lo), float(hi))


@dataclass
class FleetSummary:
    """What a log's holes add up to (:meth:`add` a batch, :meth:`merge` another summary).

    Attributes
    ----------
    tolerance_deg : float
    groups : dict, GroupKey -> Group (no histograms)
    series : dict, cell (str) -> Group (with histograms)
    worst : list of WorstHole, the :data:`WORST` holes with the largest judged angle, the worst first
    judged_after, judged_before : int, holes judged on the angle after / before the adjustment
    unknown_after : int, holes not measured after the adjustment whose before-readings do not rule out a wrong turn (HoleBatch)
    on_convention : int, with the panel known: holes judged with the head's spin taken from the cell's convention
        (no pose in the log); spin_free : int, those judged with a U95 over every spin (its spin not known);
        spin_bound : int, holes whose readings, before or judged after, rest on the spin's bound (not read);
        spin_alias : int, holes whose readings, before or judged after, the convention's alias spin sent to every
        spin (HoleBatch)
    one_sensor : int, without the panel: holes judged with rule 2b's U95, over one sensor's offset (HoleBatch)
    off_cad : OffCadSums, with the panel known; vs_cad : CadSums, with the log's commanded pose
    """

    tolerance_deg: float
    groups: dict = field(default_factory=dict)
    series: dict = field(default_factory=dict)
    worst: list = field(default_factory=list)
    judged_after: int = 0
    judged_before: int = 0
    disagree: int = 0
    unknown_after: int = 0
    on_convention: int = 0
    spin_free: int = 0
    spin_bound: int = 0
    spin_alias: int = 0
    one_sensor: int = 0
    off_cad: OffCadSums = field(default_factory=OffCadSums)
    vs_cad: CadSums = field(default_factory=CadSums)

    def vs_cad_figures(self) -> dict:
        """The against-the-CAD figures for the JSON (with the log's commanded pose): holes checked,
        holes off (|cad_offset| > CAD_OFFSET_MM), mean |offset| (mm),
        largest offset (signed, mm) and angle (deg) with their holes."""
        o = self.vs_cad
        n = o.checked
        return {"cad_checked": n, "cad_off_holes": o.holes, "cad_offset_limit_mm": CAD_OFFSET_MM,
                "cad_offset_mean_abs_mm": o.sum_abs_mm / n if n else 0.0,
                "cad_offset_max_mm": o.max_mm, "cad_offset_max_hole": o.max_mm_hole,
                "normal_vs_cad_mean_deg": o.sum_deg / n if n else 0.0, "normal_vs_cad_max_deg": o.max_deg,
                "normal_vs_cad_max_hole": o.max_deg_hole}

    def off_cad_figures(self) -> dict:
        """The panel-off-CAD figures for the JSON: holes checked (4 sensors), holes off, mean and
        largest size (1/mm: the shape change the redundant reading sees)."""
        o = self.off_cad
        return {"off_cad_sigmas": OFF_CAD_SIGMAS, "off_cad_checked": o.checked, "off_cad_holes": o.holes,
                "off_cad_mean_per_mm": o.sum_per_mm / o.holes if o.holes else 0.0,
                "off_cad_max_per_mm": o.max_per_mm, "off_cad_max_hole": o.max_hole}

    def add(self, batch: HoleBatch) -> None:
        """Count one measured batch in."""
        t = batch.columns
        g, keys = _groups(batch)
        G = len(keys)
        code = batch.status.astype(np.int64)
        counts = np.bincount(g * len(_STATUSES) + code, minlength=G * len(_STATUSES)).reshape(G, len(_STATUSES))
        judged = np.degrees(batch.judged)
        ok = np.isfinite(judged) & (code != CODE[Status.NOT_MEASURED])
        n = np.bincount(g[ok], minlength=G)
        s1 = np.bincount(g[ok], weights=judged[ok], minlength=G)
        s2 = np.bincount(g[ok], weights=judged[ok] ** 2, minlength=G)
        for j, k in enumerate(keys):
            self.groups.setdefault(k, Group()).merge(Group(counts[j], int(n[j]), float(s1[j]), float(s2[j])))
        # the histograms by cell and panel
        cps = sorted({k[0] for k in keys})
        cp_of = np.array([cps.index(k[0]) for k in keys])[g] if len(g) else np.zeros(0, int)
        nb, C = len(EDGES_DEG), len(cps)
        hists = []
        shown = np.where(ok, batch.judged, np.nan)
        for ang in (batch.angle_before, batch.angle_after, shown):
            if ang is shown and np.array_equal(shown, batch.angle_before, equal_nan=True):
                hists.append(hists[0])  # judged before the adjustment, every hole: the same angles, the same counts
                continue
            a = np.degrees(ang)
            f = np.isfinite(a)
            hists.append(np.bincount(cp_of[f] * nb + _bins(a[f]), minlength=C * nb).reshape(C, nb))
        for j, k in enumerate(cps):
            sel = [i for i, kk in enumerate(keys) if kk[0] == k]
            self.series.setdefault(k, Group()).merge(Group(counts[sel].sum(0), int(n[sel].sum()), float(s1[sel].sum()),
                                                           float(s2[sel].sum()), hists[0][j], hists[1][j],
                                                           hists[2][j]))
        after = np.isfinite(batch.angle_after)
        self.judged_after += int((ok & after).sum())
        self.judged_before += int((ok & ~after).sum())
        self.disagree += int(batch.disagree.sum()) if batch.disagree is not None else 0
        self.unknown_after += int(batch.unknown_after.sum()) if batch.unknown_after is not None else 0
        self.on_convention += int(batch.on_convention.sum()) if batch.on_convention is not None else 0
        self.spin_free += int(batch.spin_free.sum()) if batch.spin_free is not None else 0
        self.spin_bound += int(batch.spin_bound.sum()) if batch.spin_bound is not None else 0
        self.spin_alias += int(batch.spin_alias.sum()) if batch.spin_alias is not None else 0
        self.one_sensor += int(batch.one_sensor.sum()) if batch.one_sensor is not None else 0
        self.off_cad = self.off_cad.merged(OffCadSums.of(t))
        self.vs_cad = self.vs_cad.merged(CadSums.of(t))
        self._worst(batch, judged, ok)

    def _worst(self, batch, judged, ok) -> None:
        idx = np.flatnonzero(ok)
        if len(self.worst) >= WORST:  # below the WORST-th kept, a hole cannot enter (a tie may: its order decides)
            idx = idx[judged[idx] >= self.worst[WORST - 1].angle_deg]
        if not idx.size:
            return
        cand = idx
        if idx.size > WORST:  # the WORST-th largest and every tie of it: a stable sort of those alone gives
            # the full stable sort's first WORST (a million holes sorted for 20 cost 0.2 s)
            kth = np.partition(judged[idx], idx.size - WORST)[idx.size - WORST]
            cand = idx[judged[idx] >= kth]
        top = cand[np.argsort(-judged[cand], kind="stable")[:WORST]]
        t = batch.columns
        for i in top:
            self.worst.append(WorstHole(t.column("hole_id")[int(i)].as_py(), t.column(CELL)[int(i)].as_py(),
                                        t.column(PANEL)[int(i)].as_py(), float(t.column(TIME_S)[int(i)].as_py()),
                                        float(judged[i]), float(np.degrees(batch.judged_u95[i])),
                                        _STATUSES[int(batch.status[i])]))
        self.worst = sorted(self.worst, key=WorstHole.order)[:WORST]

    def merge(self, other: "FleetSummary") -> None:
        for k, grp in other.groups.items():
            self.groups.setdefault(k, Group()).merge(grp)
        for k, grp in other.series.items():
            self.series.setdefault(k, Group()).merge(grp)
        self.judged_after += other.judged_after
        self.judged_before += other.judged_before
        self.disagree += other.disagree
        self.unknown_after += other.unknown_after
        self.on_convention += other.on_convention
        self.spin_free += other.spin_free
        self.spin_bound += other.spin_bound
        self.spin_alias += other.spin_alias
        self.one_sensor += other.one_sensor
        self.off_cad = self.off_cad.merged(other.off_cad)
        self.vs_cad = self.vs_cad.merged(other.vs_cad)
        self.worst = sorted(self.worst + other.worst, key=WorstHole.order)[:WORST]

    # ------------------------------------------------------------------ figures
    def total(self) -> Group:
        out = Group()
        for grp in self.series.values():
            out.merge(grp)
        return out

    def counts(self, grp: Group | None = None) -> Counts:
        """Holes by status, of ``grp`` (None: the whole log)."""
        grp = self.total() if grp is None else grp
        return Counts(*(int(c) for c in grp.counts))

    def figures(self, grp: Group) -> Figures:
        """Quantiles (deg) of the angle before and after; the judged angle's mean, s and (a cell, the
        fleet: groups with a histogram) Ppk with its 95 % interval."""
        mean = grp.total / grp.n if grp.n else float("nan")
        var = (grp.total_sq - grp.n * mean * mean) / (grp.n - 1) if grp.n > 1 else float("nan")
        sd = float(np.sqrt(max(var, 0.0))) if np.isfinite(var) else float("nan")
        qs = (0.5, 0.95, 0.99, 0.999)
        p = ci = cap = before = after = None
        if grp.hist_judged is not None:
            p, ci = ppk(grp.hist_judged, self.tolerance_deg)
            cap = CAPABILITY
        if grp.hist_before is not None:
            before = Quantiles(*(quantile_deg(grp.hist_before, q) for q in qs))
            after = Quantiles(*(quantile_deg(grp.hist_after, q) for q in qs))
        return Figures(grp.n, mean, sd, p, ci, cap, before, after)

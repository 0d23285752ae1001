"""The drift chart's plotted series (:class:`metrology.measure.chart.CusumChart`), bounded: bins of holes,
each kept as its first, minimum, maximum and last point (the M4 aggregation of Jugel et al., 2014, "M4: a
visualization-oriented time series data aggregation", PVLDB 7(10)), neighbours merged pairwise as the series
grows, the line broken where the chart took a new baseline."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Bins", "extremes", "merge_pairs"]


@dataclass
class Bins:
    """The plotted series' bins, in time order: each bin's points in 4 slots (its first, minimum,
    maximum and last, by their order in the bin; a slot that repeats the point of the slot
    before it is not valid), or a break (no point: the line breaks there).

    Attributes
    ----------
    t : (n, 4) float, s; s : (n, 4) float, the plotted statistic (scales)
    v : (n, 4) bool, the slot holds a point of its own; br : (n,) bool, the bin is a break
    """

    t: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    s: np.ndarray = field(default_factory=lambda: np.empty((0, 4)))
    v: np.ndarray = field(default_factory=lambda: np.empty((0, 4), bool))
    br: np.ndarray = field(default_factory=lambda: np.empty(0, bool))

    @property
    def count(self) -> int:
        """The bins that are not breaks."""
        return int(len(self.br) - np.count_nonzero(self.br))

    @property
    def run(self) -> int:
        """The bins after the last break (the run a merge pairs the next bins into)."""
        brk = np.flatnonzero(self.br)
        return len(self.br) - (int(brk[-1]) + 1 if brk.size else 0)

    def add(self, t, s, v) -> None:
        """Append bins (``t``, ``s``, ``v``: (m, 4) each)."""
        self.t = np.concatenate([self.t, t])
        self.s = np.concatenate([self.s, s])
        self.v = np.concatenate([self.v, v])
        self.br = np.concatenate([self.br, np.zeros(len(t), bool)])

    def brk(self) -> None:
        """Append a break, unless there is no bin yet or the last is a break."""
        if len(self.br) and not self.br[-1]:
            self.add(np.zeros((1, 4)), np.zeros((1, 4)), np.zeros((1, 4), bool))
            self.br[-1] = True


def slots(first, lo, hi, last):
    """The 4 slots of bins whose kept points are at ``first``, ``lo``, ``hi``, ``last`` ((m,) int
    each): the positions in order (m, 4), and which hold a point of their own (m, 4)."""
    pos = np.sort(np.stack([first, lo, hi, last], axis=1), axis=1)
    valid = np.ones(pos.shape, bool)
    valid[:, 1:] = pos[:, 1:] != pos[:, :-1]
    return pos, valid


def extremes(t, s) -> tuple:
    """The points (time, value) of bins of the series that draw them as their full data would:
    each bin's first, minimum, maximum and last, in time order, each once (the M4 aggregation
    of Jugel et al., 2014, "M4: a visualization-oriented time series data aggregation", PVLDB
    7(10)). ``t``, ``s``: (m, w), a bin a row; the bins as :class:`Bins` takes them: t, s, v (m, 4)."""
    m, w = s.shape
    if m == 0:
        return np.empty((0, 4)), np.empty((0, 4)), np.empty((0, 4), bool)
    pos, valid = slots(np.zeros(m, int), np.argmin(s, axis=1), np.argmax(s, axis=1), np.full(m, w - 1))
    return np.take_along_axis(t, pos, 1), np.take_along_axis(s, pos, 1), valid


def merge_pairs(bins: Bins) -> Bins:
    """Merge neighbouring bins two by two, never across a break: each merged bin keeps the first,
    minimum, maximum and last point of both (the last bin of a run between breaks, when the run
    has an odd number, alone)."""
    rows = np.flatnonzero(~bins.br)
    run = np.cumsum(bins.br)[rows]  # each bin's run between breaks
    starts = np.flatnonzero(np.r_[True, run[1:] != run[:-1]])
    pos = np.arange(len(rows)) - np.repeat(starts, np.diff(np.r_[starts, len(rows)]))
    a = np.flatnonzero(pos % 2 == 0)  # each merged bin's first bin (in ``rows``)
    pair = (a + 1 < len(rows)) & (run[np.minimum(a + 1, len(rows) - 1)] == run[a])
    ra, rb = rows[a], rows[np.minimum(a + 1, len(rows) - 1)]
    t = np.concatenate([bins.t[ra], bins.t[rb]], axis=1)
    s = np.concatenate([bins.s[ra], bins.s[rb]], axis=1)
    v = np.concatenate([bins.v[ra], bins.v[rb] & pair[:, None]], axis=1)
    last = v.shape[1] - 1 - np.argmax(v[:, ::-1], axis=1)
    pos8, valid = slots(np.zeros(len(a), int), np.argmin(np.where(v, s, np.inf), axis=1),
                         np.argmax(np.where(v, s, -np.inf), axis=1), last)
    merged = Bins(np.take_along_axis(t, pos8, 1), np.take_along_axis(s, pos8, 1), valid, np.zeros(len(a), bool))
    # the breaks back in their places: each merged bin where its first bin was
    order = np.argsort(np.concatenate([ra, np.flatnonzero(bins.br)]), kind="stable")
    nb = int(np.count_nonzero(bins.br))
    return Bins(np.concatenate([merged.t, np.zeros((nb, 4))])[order], np.concatenate([merged.s, np.zeros((nb, 4))])[order],
                 np.concatenate([merged.v, np.zeros((nb, 4), bool)])[order],
                 np.concatenate([merged.br, np.ones(nb, bool)])[order])

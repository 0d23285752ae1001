"""A knocked sensor: a step in one sensor's zero point at a pose the data locate (registry entry)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from metrology.core.effects.base import Component, _sensor_basis

__all__ = ["Shift", "step_positions"]


def step_positions(time_h, fin, min_side):
    """Where a step can be placed among the poses with a finite reading, in time order.

    time_h : (p,) float, h (or pose index); fin : (p,) bool; min_side : int, poses each side.
    Returns ``(order (m,) int, k (K,) int)``: ``order`` the poses with a reading sorted by time
    (stable), ``k`` the admissible counts of poses before the step (a step falls between two
    distinct times, with at least ``min_side`` poses on each side).
    """
    idx = np.flatnonzero(fin)
    order = idx[np.argsort(time_h[idx], kind="stable")]
    m = len(order)
    ts = time_h[order]
    k = np.arange(min_side, m - min_side + 1)
    k = k[(k > 0) & (k < m)]
    return order, k[ts[k] > ts[k - 1]]


@dataclass(frozen=True)
class Shift(Component):
    """A step ``s`` mm in the sensor's reading from time ``at_h`` on: the sensor knocked, or its
    mount slipped, between two poses, and it stays there.

    The reading is ``d0 + s H(t - at_h)`` (``H`` the unit step, ``t`` :attr:`Covariates.time_h`, h
    since the first pose, or the pose index where the export has no time). A zero point moved by
    ``delta`` along the beam changes every later reading by ``-delta`` whatever the pose, so the
    step is the zero point's jump (the zero points of the extended model are those before it).

    Told apart from the other causes by its shape in time: a drift is smooth in time or in
    temperature, a gross reading is one reading that does not persist; a step is a jump that stays.

    ``at_h`` is not fitted by least squares: :meth:`locate` finds it by a change-point search over
    the poses in time order (the split of the residuals into a before and an after with the
    largest sum-of-squares reduction, at least :data:`MIN_SIDE_POSES` poses and
    :data:`MIN_SIDE_FRACTION` of the run each side), and :attr:`searched` (the number of splits
    tried) Bonferroni-splits the in-sample test. Unlocated (``at_h`` NaN) the step is placed at the
    middle of the run's time.

    A located step restricted to some of its poses (:meth:`select`: a fold's training poses) is
    located again among them, in the residuals it was located in (:attr:`located_in`): the
    held-out poses then judge a place chosen without them. Located on every pose, a chance
    excursion of the held-out readings has chosen the place and the held-out gain confirms it.
    The data place the knock only between the two poses that bracket it (:attr:`gap_h`): a
    reading inside that interval (a held-out pose between two training poses) is predicted by
    the step times the chance it came after the knock, the knock's time uniform in the interval
    (no pose it was located among lies inside, so their fit is the plain step's).
    """

    at_h: float = math.nan
    #: the first pose after the step and the last before it (indices of the poses it was located among)
    at_pose: int = -1
    before_pose: int = -1
    searched: int = 1
    #: the times (h) of the last pose before the step and the first after it, among those it was
    #: located among (NaN unlocated: a plain step at ``at_h``)
    gap_h: tuple = (math.nan, math.nan)
    #: ``(time_h (p,), residual (p,) mm)`` of its sensor where :meth:`locate` placed it (None unlocated)
    located_in: tuple | None = field(default=None, compare=False, repr=False)

    name = "shift"
    param_names = ("step_mm",)
    param_units = ("mm",)
    advice = "a reference pose re-measured every few poses through the run (a knock shows as a jump between them)"
    size_meaning = "step mm in the sensor's zero point (the reading's jump), at a pose drawn mid-run"
    plot_key = "time_h"
    detectable_meaning = "step in the zero point, at the least favourable pose leaving a tenth of the run each side"

    #: the fewest poses a step leaves on each side (fewer look like gross readings, which do not persist)
    MIN_SIDE_POSES = 3
    #: and at least this fraction of the run's poses on each side
    MIN_SIDE_FRACTION = 0.05
    #: the detectable size is the worst over steps leaving at least this fraction of the poses each side
    DETECT_SIDE_FRACTION = 0.1

    @classmethod
    def min_side(cls, m: int) -> int:
        return max(cls.MIN_SIDE_POSES, int(math.ceil(cls.MIN_SIDE_FRACTION * m)))

    @classmethod
    def hidden(cls, i, size):
        return cls((i,), [size])

    def _at(self, cov) -> float:
        if np.isfinite(self.at_h):
            return float(self.at_h)
        t = cov.time_h
        return 0.5 * float(np.min(t) + np.max(t))

    def basis(self, d0, cov):
        lo, hi = self.gap_h
        if np.isfinite(lo) and np.isfinite(hi):
            step = np.clip((cov.time_h - lo) / (hi - lo), 0.0, 1.0)  # 0 or 1 outside the gap
        else:
            step = (cov.time_h >= self._at(cov)).astype(float)
        cols = np.broadcast_to(step[:, None, None], d0.shape + (1,))
        return _sensor_basis(np.array(cols), d0.shape[1], self.sensors)

    def locate(self, residual, cov, sigma):
        """The step at the split of sensor ``i``'s residuals ``residual[:, i]`` (in time order)
        that explains most of their sum of squares: ``S_k^2 m / (k (m - k))``, ``S_k`` the sum of
        the centred residuals after the first ``k`` of ``m`` poses."""
        return self._split(np.asarray(cov.time_h, float), np.asarray(residual[:, self.sensors[0]], float))

    def select(self, idx):
        """Restricted to the poses ``idx`` (a fold's training poses), a located step is located
        again in its residuals at those poses only (see the class notes)."""
        if self.located_in is None:
            return self
        t, r = self.located_in
        return self._split(t[idx], r[idx])

    def _split(self, t, r):
        order, ks = step_positions(t, np.isfinite(r), self.min_side(int(np.isfinite(r).sum())))
        if len(ks) == 0:
            return self
        rs = r[order] - np.mean(r[order])
        m = len(rs)
        tail = np.cumsum(rs[::-1])[::-1]  # tail[k]: sum of rs[k:]
        gain = tail[ks] ** 2 * m / (ks * (m - ks))
        k = int(ks[int(np.argmax(gain))])
        ts = t[order]
        return replace(self, at_h=0.5 * float(ts[k - 1] + ts[k]), at_pose=int(order[k]),
                       before_pose=int(order[k - 1]), searched=int(len(ks)), values=None, stderr=None,
                       gap_h=(float(ts[k - 1]), float(ts[k])),
                       located_in=(t, r))

    def size_rows(self, d0, cov):
        return np.ones((1, 1)), "the step in the sensor's zero point (its absolute value)"

    def detectable_size(self, J_i, cov, fin, sigma_i, alpha):
        """The step (mm) its in-sample test (``alpha`` split over the positions searched) detects
        at 95 % power, at the least favourable position leaving :data:`DETECT_SIDE_FRACTION` of
        the poses each side: the part of the step the sensor's five base columns ``J_i`` do not
        take, whitened by ``sigma_i``, is its noncentrality per mm squared."""
        from scipy import optimize, stats

        m = int(np.sum(fin))
        order, ks = step_positions(np.asarray(cov.time_h, float), fin, self.min_side(m))
        if len(ks) == 0 or m <= 7:
            return None
        dof = m - 6
        crit = float(stats.f.isf(alpha / len(ks), 1, dof))
        lam95 = optimize.brentq(lambda lam: float(stats.ncf.sf(crit, 1, dof, lam)) - 0.95, 0.0, 1e6)
        wide = ks[(ks >= math.ceil(self.DETECT_SIDE_FRACTION * m)) & (ks <= m - math.ceil(self.DETECT_SIDE_FRACTION * m))]
        wide = wide if len(wide) else ks
        X0 = J_i[order] / sigma_i
        H = (np.arange(m)[:, None] >= wide[None, :]).astype(float) / sigma_i  # (m, K) unit steps
        Q, _ = np.linalg.qr(X0)
        R = H - Q @ (Q.T @ H)
        lam1 = np.sum(R**2, axis=0)
        return float(np.sqrt(lam95 / max(float(np.min(lam1)), 1e-300)))

    def describe(self):
        out = super().describe()
        out["at"] = {"time_h": float(self.at_h), "first_pose_after": self.at_pose, "last_pose_before": self.before_pose,
                     "positions_searched": self.searched}
        return out

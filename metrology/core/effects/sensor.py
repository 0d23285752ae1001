"""Effects of one sensor: gain, incidence, drift, linearity (registry entries)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects.base import REFERENCE_TEMP_C, Component, _sensor_basis

__all__ = ["Scale", "Incidence", "Drift", "Nonlinearity"]


@dataclass(frozen=True)
class Scale(Component):
    """Gain error ``k``: the reading is ``(1 + k) d0`` (a constant part is a zero shift)."""

    name = "scale"
    param_names = ("k",)
    param_units = ("1",)
    uses_d0 = True
    advice = "readings over the whole measuring range (a wider spread of stand-off)"
    size_meaning = "gain error k (unitless)"
    plot_key = "d_mm"

    def basis(self, d0, cov):
        return _sensor_basis(d0[..., None], d0.shape[1], self.sensors)

    def d_dd0(self, values, d0, cov):
        return np.where(self._mask(d0.shape[1])[None, :], values[0], 0.0) * np.ones_like(d0)


@dataclass(frozen=True)
class Incidence(Component):
    """Bias ``c tan^2(gamma)``: grows from zero at normal incidence, ``c`` mm at 45 deg.

    A triangulation sensor's spot elongates as ``1/cos(gamma)`` on a tilted surface and the
    centroid of its image shifts with the speckle and intensity gradient across it; the
    manufacturers' curves of error against tilt are even in the angle and grow faster than
    linearly: ``tan^2`` is the lowest-order even form that vanishes at normal incidence.
    """

    name = "incidence"
    param_names = ("c_mm",)
    param_units = ("mm",)
    advice = "a wider spread of tilt against the datum (incidence angles)"
    size_meaning = "c mm (bias at 45 deg incidence)"
    plot_key = "incidence_deg"

    def basis(self, d0, cov):
        t2 = 1.0 / cov.cos_inc**2 - 1.0
        return _sensor_basis(t2[..., None], d0.shape[1], self.sensors)


@dataclass(frozen=True)
class Drift(Component):
    """Zero drift ``r (T - T_ref)`` with temperature (``variable="temp"``, mm/K) or
    ``r (t - t_ref)`` with time (``variable="time"``, mm/h): warm-up of the sensor and
    thermal growth of its mount.

    ``ref`` is a fixed reference, never the first pose of whatever subset is evaluated (a
    k-fold held-out set would then be shifted by ``r`` times the difference of its first
    temperature and the training set's). The zero points of the extended model are those at
    ``ref``; a constant part is a zero shift, so ``ref`` changes the zero point, not the rate
    or the fit, but it sets how strongly the rate correlates with the zero point (least at
    the run's mean, which the diagnosis uses). Default :data:`REFERENCE_TEMP_C` (20 deg C,
    the reference temperature of dimensional metrology, ISO 1) for temperature, 0 h (the
    run's first pose) for time.

    ``order=3`` makes the drift a smooth curve rather than a line: ``p1 P1(x) + p2 P2(x) +
    p3 P3(x)`` with ``x = (v - ref) / half`` the variable normalised over the run (``half`` its
    half-span, fixed per data set like ``ref``), ``p1..p3`` mm at the run's end. A warm-up
    that levels off, a lagged temperature or a warm-cool cycle is not linear in either
    variable; the diagnosis scores both orders and names ``drift`` for either.
    """

    variable: str = "temp"
    ref: float | None = None
    order: int = 1
    half: float = 1.0

    name = "drift"
    advice = "poses repeated cold and warm, interleaved rather than in one sweep"
    size_meaning = "rate mm/K (temperature)"

    @property
    def plot_key(self):
        return "temp_c" if self.variable == "temp" else "time_h"

    @classmethod
    def candidates_for_sensor(cls, i, names, cov):
        # the reference is fixed once per data set (every fold evaluates against it) at the
        # run's mean, where the rate is least correlated with the zero point
        out = []
        if np.all(np.isfinite(cov.temp_c)) and np.ptp(cov.temp_c) > 0:
            out.append(cls((i,), names=names, variable="temp", ref=float(np.mean(cov.temp_c))))
        t = cov.time_h
        out.append(cls((i,), names=names, variable="time", ref=float(np.mean(t))))
        if np.ptp(t) > 0:
            mid, half = 0.5 * float(np.max(t) + np.min(t)), 0.5 * float(np.ptp(t))
            out.append(cls((i,), names=names, variable="time", ref=mid, order=3, half=half))
        return out

    @classmethod
    def hidden(cls, i, size):
        return cls((i,), [size], variable="temp")

    @property
    def param_names(self):
        if self.order == 3:
            return ("p1_mm", "p2_mm", "p3_mm")
        return ("rate_mm_per_K",) if self.variable == "temp" else ("rate_mm_per_h",)

    @property
    def param_units(self):
        if self.order == 3:
            return ("mm",) * 3
        return ("mm/K",) if self.variable == "temp" else ("mm/h",)

    def __post_init__(self):
        if self.variable not in ("temp", "time"):
            raise ValueError(f"drift variable must be 'temp' or 'time', got {self.variable!r}")
        if self.order not in (1, 3) or not self.half > 0:
            raise ValueError(f"drift order must be 1 or 3 with a positive half-span, got {self.order}, {self.half}")
        if self.ref is None:
            object.__setattr__(self, "ref", REFERENCE_TEMP_C if self.variable == "temp" else 0.0)
        super().__post_init__()

    @property
    def label(self):
        return super().label + ("@temp" if self.variable == "temp" else "@time") + ("3" if self.order == 3 else "")

    def covariate(self, cov):
        """``(p,)``: ``T - ref`` (K) or ``t - ref`` (h) of the poses of ``cov``."""
        x = cov.temp_c if self.variable == "temp" else cov.time_h
        if not np.all(np.isfinite(x)):
            raise ValueError(f"drift with {self.variable}: the export has no {self.variable} column")
        return x - self.ref

    def describe(self):
        out = super().describe()
        out["reference"] = {"value": float(self.ref), "unit": "deg C" if self.variable == "temp" else "h"}
        return out

    def basis(self, d0, cov):
        v = self.covariate(cov)
        if self.order == 3:
            x = v / self.half
            cols = np.stack([x, *_legendre23(x)], axis=-1)  # (p, 3)
        else:
            cols = v[:, None]
        x = np.broadcast_to(cols[:, None, :], d0.shape + (cols.shape[1],))
        return _sensor_basis(np.array(x), d0.shape[1], self.sensors)


def _legendre23(x):
    return 0.5 * (3 * x**2 - 1), 0.5 * (5 * x**3 - 3 * x)


@dataclass(frozen=True)
class Nonlinearity(Component):
    """Linearity error ``c2 P2(x) + c3 P3(x)`` over the normalised range ``x`` in [-1, 1].

    The datasheet's linearity error is the deviation from the best straight line over the
    full range, so its constant and linear parts are zero by definition: the first two
    Legendre polynomials orthogonal to them are the bow (``P2``) and the S-shape (``P3``);
    ``c2``, ``c3`` are their values at the end of the range (mm).

    ``with_gain=True`` adds the gain ``k d0`` (the linear part, as :class:`Scale`): the sensor's
    whole characteristic to third order. The diagnosis scores this family member beside
    ``scale`` and names ``nonlinearity`` only when the curve predicts held-out poses
    significantly better than the gain alone (a real characteristic, e.g. an S-curve that
    flattens at one end, has both parts).
    """

    with_gain: bool = False

    name = "nonlinearity"
    uses_d0 = True
    advice = "readings over the whole measuring range (a wider spread of stand-off)"
    size_meaning = "c3 mm at the range end (c2 = c3/2)"
    plot_key = "d_mm"

    @classmethod
    def hidden(cls, i, size):
        return cls((i,), [0.5 * size, size])

    @classmethod
    def candidates_for_sensor(cls, i, names, cov):
        return [cls((i,), names=names, with_gain=True)]

    @property
    def param_names(self):
        return (("k",) if self.with_gain else ()) + ("c2_mm", "c3_mm")

    @property
    def param_units(self):
        return (("1",) if self.with_gain else ()) + ("mm", "mm")

    def _x(self, d0, cov):
        lo, hi = cov.range_mm[:, 0], cov.range_mm[:, 1]
        return (2 * d0 - lo - hi) / (hi - lo), 2.0 / (hi - lo)

    def basis(self, d0, cov):
        x, _ = self._x(d0, cov)
        p2, p3 = _legendre23(x)
        cols = ([d0] if self.with_gain else []) + [p2, p3]
        return _sensor_basis(np.stack(cols, axis=-1), d0.shape[1], self.sensors)

    def d_dd0(self, values, d0, cov):
        x, dx = self._x(d0, cov)
        g = values[0] if self.with_gain else 0.0
        c2, c3 = values[-2], values[-1]
        deriv = g + (c2 * 3 * x + c3 * 0.5 * (15 * x**2 - 3)) * dx[None, :]
        return np.where(self._mask(d0.shape[1])[None, :], deriv, 0.0)


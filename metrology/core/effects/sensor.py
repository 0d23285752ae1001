"""Effects of the conditions of one sensor's reading on it: the beam's incidence on the surface
(:class:`Incidence`) and the zero's drift with temperature or time (:class:`Drift`) (registry entries). Its
characteristic, gain and linearity: :mod:`metrology.core.effects.characteristic`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects.base import REFERENCE_TEMP_C, Component, _sensor_basis
from metrology.core.effects.characteristic import legendre23

__all__ = ["Incidence", "Drift"]


@dataclass(frozen=True)
class Incidence(Component):
    """Bias ``c tan^2(gamma)``: grows from zero at normal incidence, ``c`` mm at 45 deg.

    A triangulation sensor's spot elongates as ``1/cos(gamma)`` on a tilted surface and the
    centroid of its image shifts with the speckle and intensity gradient across it; the
    manufacturers' curves of error against tilt are even in the angle and grow faster than
    linearly: ``tan^2`` is the lowest-order even form that vanishes at normal incidence.

    ``order=4`` is the family's richer member ``c2 tan^2(gamma) + c4 tan^4(gamma)`` (mm at
    45 deg each): an even curve that steepens or flattens at large angles (a sensor whose
    error stays small up to some angle and then grows quickly, or one that saturates), which
    ``tan^2`` alone leaves as structure. The diagnosis takes it only when it predicts held-out
    poses significantly better than ``tan^2``.
    """

    order: int = 2

    name = "incidence"
    advice = "a wider spread of tilt against the datum (incidence angles)"
    size_meaning = "c mm (bias at 45 deg incidence)"
    plot_key = "incidence_deg"
    confused_with = ("crosstalk",)
    detectable_meaning = "bias at the largest incidence angle seen, the least favourable even shape"
    worst_shape = True
    #: the even shapes ``(a / a_max)^k`` (``a`` the incidence angle) over which the detectable size is the worst
    SHAPE_POWERS = (2, 4, 6)

    def size_rows(self, d0, cov):
        i = self.sensors[0]
        j = int(np.argmin(cov.cos_inc[:, i]))
        return self.basis(d0, cov)[j:j + 1, i, :], "bias at the largest incidence angle seen"

    def detectable_direction(self):
        return np.ones(1) if self.n_params == 1 else None

    @classmethod
    def detectable_shapes(cls, d0_i, cos_inc_i, fin):
        """Any even bias: one that grows slowly with the angle (``a^2``) changes least over the
        angles seen for its value at the largest, so the zero point takes most of it."""
        a = np.where(fin, np.arccos(np.clip(cos_inc_i, -1.0, 1.0)), np.nan)
        a_max = float(np.nanmax(a)) if fin.any() else 0.0
        return [(a / a_max) ** k for k in cls.SHAPE_POWERS] if a_max > 0 else []

    @classmethod
    def candidates_for_sensor(cls, i, names, cov):
        return [cls((i,), names=names), cls((i,), names=names, order=4)]

    def __post_init__(self):
        if self.order not in (2, 4):
            raise ValueError(f"incidence order must be 2 or 4, got {self.order}")
        super().__post_init__()

    @property
    def param_names(self):
        return ("c2_mm", "c4_mm") if self.order == 4 else ("c_mm",)

    @property
    def param_units(self):
        return ("mm",) * len(self.param_names)

    @property
    def label(self):
        return super().label + ("@4" if self.order == 4 else "")

    def basis(self, d0, cov):
        t2 = 1.0 / cov.cos_inc**2 - 1.0
        cols = np.stack([t2, t2**2], axis=-1) if self.order == 4 else t2[..., None]
        return _sensor_basis(cols, d0.shape[1], self.sensors)


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

    ``variable="lag"`` is the thermal member: ``r0 (T - ref) + r1 (T_1 - ref) + r2 (T_2 - ref)``
    with ``T_1``, ``T_2`` the temperature seen through first-order lags
    (:attr:`Covariates.temp_lag`, time constants ``LAG_FRACTIONS`` of the run), mm/K each: a
    head whose zero follows the air with a lag of minutes.
    """

    variable: str = "temp"
    ref: float | None = None
    order: int = 1
    half: float = 1.0

    name = "drift"
    advice = "poses repeated cold and warm, interleaved rather than in one sweep"
    size_meaning = "rate mm/K (temperature)"
    detectable_meaning = "peak-to-valley over the run of a linear drift"

    @property
    def tie_rank(self) -> int:
        """Temperature wins a tie (the physical cause, time its proxy)."""
        return 0 if self.variable in ("temp", "lag") else 1

    def size_rows(self, d0, cov):
        return self.basis(d0, cov)[:, self.sensors[0], :], "peak-to-valley of the drift over the run"

    def detectable_direction(self):
        return np.ones(1) if self.n_params == 1 else None

    @property
    def plot_key(self):
        return "time_h" if self.variable == "time" else "temp_c"

    @classmethod
    def candidates_for_sensor(cls, i, names, cov):
        # the reference is fixed once per data set (every fold evaluates against it) at the
        # run's mean, where the rate is least correlated with the zero point
        out = []
        if np.all(np.isfinite(cov.temp_c)) and np.ptp(cov.temp_c) > 0:
            out.append(cls((i,), names=names, variable="temp", ref=float(np.mean(cov.temp_c))))
        if cov.temp_lag is not None and np.all(np.isfinite(cov.temp_c)) and np.ptp(cov.temp_c) > 0:
            out.append(cls((i,), names=names, variable="lag", ref=float(np.mean(cov.temp_c))))
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
        if self.variable == "lag":
            return ("rate_mm_per_K", "rate_lag1_mm_per_K", "rate_lag2_mm_per_K")
        return ("rate_mm_per_K",) if self.variable == "temp" else ("rate_mm_per_h",)

    @property
    def param_units(self):
        if self.order == 3:
            return ("mm",) * 3
        if self.variable == "lag":
            return ("mm/K",) * 3
        return ("mm/K",) if self.variable == "temp" else ("mm/h",)

    def __post_init__(self):
        if self.variable not in ("temp", "time", "lag"):
            raise ValueError(f"drift variable must be 'temp', 'time' or 'lag', got {self.variable!r}")
        if self.order not in (1, 3) or not self.half > 0 or (self.variable == "lag" and self.order != 1):
            raise ValueError(f"drift order must be 1 or 3 with a positive half-span, got {self.order}, {self.half}")
        if self.ref is None:
            object.__setattr__(self, "ref", 0.0 if self.variable == "time" else REFERENCE_TEMP_C)
        super().__post_init__()

    @property
    def label(self):
        return super().label + "@" + self.variable + ("3" if self.order == 3 else "")

    def covariate(self, cov):
        """``(p,)``: ``T - ref`` (K) or ``t - ref`` (h) of the poses of ``cov``."""
        x = cov.time_h if self.variable == "time" else cov.temp_c
        if not np.all(np.isfinite(x)):
            raise ValueError(f"drift with {self.variable}: the export has no {self.variable} column")
        if self.variable == "lag":
            if cov.temp_lag is None:
                raise ValueError("drift with lag: the covariates have no lagged temperature (no time or temperature)")
            return np.column_stack([x, cov.temp_lag]) - self.ref
        return x - self.ref

    def describe(self):
        out = super().describe()
        out["reference"] = {"value": float(self.ref), "unit": "h" if self.variable == "time" else "deg C"}
        return out

    def basis(self, d0, cov):
        v = self.covariate(cov)
        if self.order == 3:
            x = v / self.half
            cols = np.stack([x, *legendre23(x)], axis=-1)  # (p, 3)
        elif v.ndim == 2:  # the temperature and its lagged copies (p, 3)
            cols = v
        else:
            cols = v[:, None]
        x = np.broadcast_to(cols[:, None, :], d0.shape + (cols.shape[1],))
        return _sensor_basis(np.array(x), d0.shape[1], self.sensors)

"""Sensor characteristics: the reading error as a function of the true distance.

A sensor whose characteristic is ``e(d)`` reads ``d_true + e(d_true)`` (mm). Every curve is
defined on the sensor's range ``[lo, hi]`` mm; ``x = (d - lo) / (hi - lo)`` in [0, 1]:

- ``gain``: ``e = g d`` (a scale error; ``g`` unitless, e.g. 1e-3 is 1 um per mm);
- ``table``: a shape-preserving (PCHIP) cubic through knots ``(d_k, e_k)`` mm: it passes
  through every knot and is monotone between knots that are;
- ``s_curve``: ``e = A (x - softplus_w(x - x0))`` flipped to either end: linear with slope ``A``
  mm per unit x, flattening smoothly past ``x0`` (width ``w``);
- ``tanh``: ``e = A tanh((x - x0) / w)``.

``draw_curve`` scales any of them so the peak-to-valley of ``e`` over ``[lo, hi]`` equals a
given size (mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Characteristic", "draw_curve", "CURVE_SHAPES"]

CURVE_SHAPES = ("gain", "table", "s_curve", "tanh")


@dataclass(frozen=True)
class Characteristic:
    """A reading-error curve ``e(d)`` mm on the range ``lo..hi`` mm (see the module docstring).

    Attributes
    ----------
    shape : str, one of ``CURVE_SHAPES``
    lo, hi : float, mm
    params : dict of float or list, the shape's parameters (``gain``; ``knots_mm``, ``values_mm``;
        ``amplitude_mm``, ``x0``, ``width``, ``flip``)
    """

    shape: str
    lo: float
    hi: float
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.shape not in CURVE_SHAPES:
            raise ValueError(f"characteristic shape must be one of {CURVE_SHAPES}, got {self.shape!r}")
        if not self.hi > self.lo:
            raise ValueError(f"characteristic range must have lo < hi, got {self.lo}, {self.hi}")

    def __call__(self, d):
        """Reading error ``e`` mm at true distances ``d`` (...) mm; NaN stays NaN."""
        d = np.asarray(d, float)
        x = (d - self.lo) / (self.hi - self.lo)
        p = self.params
        if self.shape == "gain":
            return p["gain"] * d
        if self.shape == "table":
            from scipy.interpolate import PchipInterpolator

            return PchipInterpolator(p["knots_mm"], p["values_mm"], extrapolate=True)(d)
        if self.shape == "s_curve":
            xx = 1.0 - x if p["flip"] else x
            z = (xx - p["x0"]) / p["width"]
            soft = p["width"] * np.logaddexp(0.0, z)
            return p["amplitude_mm"] * (xx - soft)
        return p["amplitude_mm"] * np.tanh((x - p["x0"]) / p["width"])

    def peak_to_valley(self, n_grid: int = 401) -> float:
        """Peak-to-valley of ``e`` mm over ``[lo, hi]``."""
        e = self(np.linspace(self.lo, self.hi, n_grid))
        return float(e.max() - e.min())

    def to_dict(self) -> dict:
        out = {"shape": self.shape, "lo_mm": self.lo, "hi_mm": self.hi}
        out.update({k: (np.asarray(v).tolist() if isinstance(v, (list, np.ndarray)) else v) for k, v in self.params.items()})
        return out


def draw_curve(rng: np.random.Generator, shape: str, lo: float, hi: float, size_mm: float) -> Characteristic:
    """A random curve of ``shape`` on ``[lo, hi]`` mm with peak-to-valley ``size_mm``.

    ``gain`` gets a random sign; ``table`` 4-7 knots jittered about an even spacing (never closer than half of it) with random values;
    ``s_curve`` a knee ``x0`` in [0.35, 0.75], width 0.04-0.15 and a random end to flatten;
    ``tanh`` a centre in [0.3, 0.7] and width 0.1-0.4.
    """
    if shape == "gain":
        sign = rng.choice([-1.0, 1.0])
        return Characteristic("gain", lo, hi, {"gain": float(sign * size_mm / (hi - lo))})
    if shape == "table":
        k = int(rng.integers(4, 8))
        # knots jittered about an even spacing, never closer than half of it: two knots a few
        # um apart with different values make a step, which no smooth characteristic has
        step = 1.0 / (k - 1)
        x = np.linspace(0.0, 1.0, k)
        x[1:-1] += rng.uniform(-0.25, 0.25, k - 2) * step
        v = rng.normal(size=k)
        while np.ptp(v) == 0:
            v = rng.normal(size=k)
        raw = Characteristic("table", lo, hi, {"knots_mm": (lo + x * (hi - lo)).tolist(), "values_mm": v.tolist()})
        scale = size_mm / raw.peak_to_valley()
        return Characteristic("table", lo, hi, {"knots_mm": raw.params["knots_mm"], "values_mm": (scale * v).tolist()})
    if shape == "s_curve":
        params = {"amplitude_mm": 1.0, "x0": float(rng.uniform(0.35, 0.75)), "width": float(rng.uniform(0.04, 0.15)),
                  "flip": bool(rng.integers(2))}
    elif shape == "tanh":
        params = {"amplitude_mm": 1.0, "x0": float(rng.uniform(0.3, 0.7)), "width": float(rng.uniform(0.1, 0.4))}
    else:
        raise ValueError(f"characteristic shape must be one of {CURVE_SHAPES}, got {shape!r}")
    sign = float(rng.choice([-1.0, 1.0]))
    raw = Characteristic(shape, lo, hi, params)
    params["amplitude_mm"] = sign * size_mm / raw.peak_to_valley()
    return Characteristic(shape, lo, hi, params)

"""Incidence bias: a reading error that is an even function of the true incidence angle.

``a`` (rad) is the angle between the beam and the local surface normal (:mod:`.beams`); the bias
``b(a)`` (mm) is added to the reading. Shapes (all even in ``a``, zero at normal incidence):

- ``one_minus_cos``: ``k (1 - cos a)``;
- ``quadratic``: ``k a^2``;
- ``even_poly``: ``sum_j c_j a^(2j)``, ``j = 1..3`` with random ``c_j`` (normalised);
- ``tan_poly`` (a head's stated response, never drawn at random): ``sum_j c_j tan(a)^(2j)``.

``draw_incidence`` scales the curve so ``b`` at the largest angle seen equals the size (mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["IncidenceBias", "draw_incidence", "INCIDENCE_SHAPES"]

INCIDENCE_SHAPES = ("one_minus_cos", "quadratic", "even_poly")


@dataclass(frozen=True)
class IncidenceBias:
    """``b(a)`` mm, ``a`` rad (see the module docstring). ``params``: ``k_mm`` or ``coeffs_mm``."""

    shape: str
    params: dict = field(default_factory=dict)

    def __call__(self, angle):
        a = np.asarray(angle, float)
        p = self.params
        if self.shape == "one_minus_cos":
            return p["k_mm"] * (1 - np.cos(a))
        if self.shape == "quadratic":
            return p["k_mm"] * a**2
        if self.shape == "even_poly":
            return sum(c * a ** (2 * (j + 1)) for j, c in enumerate(p["coeffs_mm"]))
        if self.shape == "tan_poly":  # a stated response: sum_j c_j tan(a)^(2j), mm (a spot elongating as 1/cos a)
            t2 = np.tan(a) ** 2
            return sum(c * t2 ** (j + 1) for j, c in enumerate(p["coeffs_mm"]))
        raise ValueError(f"incidence shape must be one of {INCIDENCE_SHAPES}, got {self.shape!r}")

    def to_dict(self) -> dict:
        return {"shape": self.shape, **{k: (list(v) if isinstance(v, (list, tuple, np.ndarray)) else v)
                                        for k, v in self.params.items()}}


def draw_incidence(rng: np.random.Generator, max_angle_rad: float, size_mm: float, shape: str | None = None) -> IncidenceBias:
    """A random even bias with ``b(max_angle_rad) = +-size_mm``."""
    shape = shape or INCIDENCE_SHAPES[int(rng.integers(len(INCIDENCE_SHAPES)))]
    if not max_angle_rad > 0:
        raise ValueError(f"incidence: the largest incidence angle must be positive, got {max_angle_rad}")
    sign = float(rng.choice([-1.0, 1.0]))
    if shape in ("one_minus_cos", "quadratic"):
        raw = IncidenceBias(shape, {"k_mm": 1.0})
        return IncidenceBias(shape, {"k_mm": sign * size_mm / float(raw(max_angle_rad))})
    if shape == "even_poly":
        c = np.abs(rng.normal(size=3)) * np.array([1.0, 1.0, 1.0]) / max_angle_rad ** np.array([2, 4, 6])
        c = c * (rng.random(3) < 0.8)
        c[0] = c[0] or 1.0 / max_angle_rad**2  # keep a quadratic term so the curve is not empty
        raw = IncidenceBias(shape, {"coeffs_mm": c.tolist()})
        return IncidenceBias(shape, {"coeffs_mm": (sign * size_mm / float(raw(max_angle_rad)) * c).tolist()})
    raise ValueError(f"incidence shape must be one of {INCIDENCE_SHAPES}, got {shape!r}")

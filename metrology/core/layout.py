"""The sensor layout: zero points and beam directions of n >= 3 sensors (mm, unit vectors, TCS).

Its TOML file is read and written by :mod:`metrology.io.layout`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import numpy as np

#: names of the five identifiable parameters of a sensor's chart (the zero point's x, y, z; the beam's
#: tangent a, b): the calibration's parameters and the layout's ``[calibration]`` covariance
PARAMS_TANGENT = ("x", "y", "z", "a", "b")


@dataclass(frozen=True)
class SensorLayout:
    """Zero points and beam directions of the sensors on the pressure foot.

    Attributes
    ----------
    names : tuple of str, length n
    zero : (n, 3) float, mm, TCS
    direction : (n, 3) float, unit, TCS
    noise_mm : (n,) float, mm, 1 sigma reading repeatability; NaN where not stated
    range_mm : (n, 2) float, mm, valid reading interval; (-inf, inf) where not stated
    zero_stderr_mm : (n, 3) float, mm, or None (a nominal layout)
    direction_stderr_deg : (n, 2) float, deg, or None
    effects : HeadTerms or None: the head's effect terms (:mod:`metrology.core.effects.terms`) with
        their covariance, which every consumer applies (:mod:`metrology.core.effects.apply`); None:
        the simple model
    covariance : (5n, 5n) float, mm and rad, or None (a nominal layout)
        The calibration's covariance of the five identifiable parameters of every sensor,
        ``(x, y, z, a, b)`` per sensor in layout order: the zero point (mm, TCS) and the beam's
        tilt (rad) about the axes ``e1, e2`` of :func:`metrology.core.model.direction_basis`
        of the layout's *own* directions (the chart centred on the calibrated beam). The
        direction is a unit vector: its sixth number (the scale) is not a parameter.
    certificate : dict of str -> str
        The calibration certificate's header fields (part, operator, instrument, serial,
        temperature, notes, ...), carried with a calibrated layout; empty for a nominal one.
    """

    names: tuple
    zero: np.ndarray
    direction: np.ndarray
    noise_mm: np.ndarray | None = None
    range_mm: np.ndarray | None = None
    zero_stderr_mm: np.ndarray | None = None
    direction_stderr_deg: np.ndarray | None = None
    effects: object = None
    covariance: np.ndarray | None = None
    certificate: dict = field(default_factory=dict)

    def __post_init__(self):
        n = len(self.names)
        zero = np.asarray(self.zero, dtype=float).reshape(n, 3)
        direction = np.asarray(self.direction, dtype=float).reshape(n, 3)
        if n < 3:
            raise ValueError(f"a layout needs at least 3 sensors, got {n}")
        if len(set(self.names)) != n:
            raise ValueError(f"sensor names must be unique, got {list(self.names)}")
        if not (np.all(np.isfinite(zero)) and np.all(np.isfinite(direction))):
            raise ValueError("layout zero points and directions must be finite")
        norms = np.linalg.norm(direction, axis=1)
        if np.any(norms == 0):
            raise ValueError("a beam direction is the zero vector")
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "zero", zero)
        object.__setattr__(self, "direction", direction / norms[:, None])
        noise = np.full(n, np.nan) if self.noise_mm is None else np.asarray(self.noise_mm, float).reshape(n)
        object.__setattr__(self, "noise_mm", noise)
        rng = np.tile([-np.inf, np.inf], (n, 1)) if self.range_mm is None else np.asarray(self.range_mm, float).reshape(n, 2)
        object.__setattr__(self, "range_mm", rng)
        if self.covariance is not None:
            cov = np.asarray(self.covariance, float)
            if cov.shape != (5 * n, 5 * n) or not np.all(np.isfinite(cov)):
                raise ValueError(f"covariance must be a finite ({5 * n}, {5 * n}) matrix for {n} sensors, got shape {cov.shape}")
            object.__setattr__(self, "covariance", 0.5 * (cov + cov.T))

    @property
    def n(self) -> int:
        return len(self.names)

    def with_params(self, zero, direction, **kw) -> "SensorLayout":
        """A copy with new zero points ``(n, 3)`` mm and directions ``(n, 3)`` (normalised)."""
        return replace(self, zero=np.asarray(zero, float), direction=np.asarray(direction, float), **kw)

    def subset(self, names) -> "SensorLayout":
        idx = [self.names.index(nm) for nm in names]
        return SensorLayout(
            tuple(names), self.zero[idx], self.direction[idx], self.noise_mm[idx], self.range_mm[idx],
            None if self.zero_stderr_mm is None else self.zero_stderr_mm[idx],
            None if self.direction_stderr_deg is None else self.direction_stderr_deg[idx],
            None if self.effects is None else self.effects.subset(tuple(names), self.names),
            None if self.covariance is None else self.covariance[np.ix_(_rows(idx), _rows(idx))],
        )


def _rows(idx):
    """The rows of the covariance of sensors ``idx`` (five per sensor)."""
    return [5 * i + k for i in idx for k in range(5)]

"""What the calibration sees: the datum plane in each pose's tool frame, and the readings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Observations:
    """The datum plane in each pose's TCS and the readings.

    Attributes
    ----------
    normal : (p, 3) float, unit, TCS
    offset : (p,) float, mm
    d : (p, n) float, mm; NaN = no reading
    """

    normal: np.ndarray
    offset: np.ndarray
    d: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "normal", np.atleast_2d(np.asarray(self.normal, float)))
        object.__setattr__(self, "offset", np.atleast_1d(np.asarray(self.offset, float)))
        object.__setattr__(self, "d", np.atleast_2d(np.asarray(self.d, float)))
        p = len(self.offset)
        if self.normal.shape != (p, 3) or self.d.shape[0] != p:
            raise ValueError(f"observations: normal {self.normal.shape}, offset {self.offset.shape}, d {self.d.shape} disagree")

    @property
    def n_poses(self) -> int:
        return len(self.offset)

    def select(self, idx) -> "Observations":
        return Observations(self.normal[idx], self.offset[idx], self.d[idx])

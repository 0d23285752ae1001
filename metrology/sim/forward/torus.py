"""A torus lip: an inlet's or a nacelle's lip, tight across and gentle around (issue 53).

Panel frame (mm) as in :mod:`.panels`: the surface passes through the origin with its outward unit
normal ``+z`` there, the head on the ``+z`` side. The torus has a tube of radius ``r`` (the lip's
tight radius, across it: along ``y``) about a ring of radius ``Rm`` whose axis runs along ``y``:

- ``outer`` (the lip's outside, the ring's axis below the panel at ``z = -(Rm + r)``): the surface
  lies at ``Rm + sqrt(r^2 - y^2)`` from that axis, ``f = sqrt((Rm + sqrt(r^2 - y^2))^2 - x^2) - Rm - r``;
  both curvatures convex at the origin, ``1/r`` along ``y`` and ``1/(Rm + r)`` along ``x``;
- ``inner`` (the inlet's inside, the head between the lip and the axis at ``z = Rm - r``): the surface
  lies at ``Rm - sqrt(r^2 - y^2)`` from it, ``f = Rm - r - sqrt((Rm - sqrt(r^2 - y^2))^2 - x^2)``; a
  saddle at the origin, ``+1/r`` along ``y``, ``-1/(Rm - r)`` along ``x``.

The lip's crest is the ``x`` axis (``y = 0``): :attr:`TorusPanel.axis`. Rays, normals and shape
operators are the height field's (:class:`metrology.sim.forward.shapes.HeightPanel`: Newton along the
ray, central differences); the formulas above are the torus's own geometry, nothing of the model's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metrology.sim.forward.shapes import HeightPanel

__all__ = ["TorusPanel", "LIP_SIDES"]

#: the sides of the lip the head may work on (module docstring)
LIP_SIDES = ("outer", "inner")


@dataclass(frozen=True)
class TorusPanel(HeightPanel):
    """A torus lip of tube radius ``tube_mm`` about a ring of radius ``ring_mm`` (module docstring).

    Attributes
    ----------
    tube_mm : float, mm, the lip's radius across it (along ``y``)
    ring_mm : float, mm, the ring's radius (its axis along ``y``), more than ``tube_mm``
    side : str, ``"outer"`` or ``"inner"``
    """

    tube_mm: float
    ring_mm: float = 600.0
    side: str = "outer"
    kind = "torus"
    #: the crest line's direction (the holes of a lip run around it)
    axis = (1.0, 0.0, 0.0)

    def __post_init__(self):
        r, Rm = self.tube_mm, self.ring_mm
        if not (r > 0 and math.isfinite(r) and math.isfinite(Rm) and Rm > r):
            raise ValueError(f"torus lip: the tube radius must be positive and under the ring's, got r {r}, Rm {Rm}")
        if self.side not in LIP_SIDES:
            raise ValueError(f"torus lip side {self.side!r}: expected one of {', '.join(LIP_SIDES)}")

    @property
    def curvatures(self) -> tuple:
        """``(k_x, k_y)`` 1/mm at the origin, positive where the surface bends away from the head."""
        r, Rm = self.tube_mm, self.ring_mm
        return (1.0 / (Rm + r), 1.0 / r) if self.side == "outer" else (-1.0 / (Rm - r), 1.0 / r)

    def f(self, x, y):
        r, Rm = self.tube_mm, self.ring_mm
        x, y = np.asarray(x, float), np.asarray(y, float)
        with np.errstate(invalid="ignore"):
            c = np.sqrt(r * r - y * y)
            if self.side == "outer":
                return np.sqrt((Rm + c) ** 2 - x * x) - Rm - r
            return Rm - r - np.sqrt((Rm - c) ** 2 - x * x)

    def to_dict(self):
        return {"kind": self.kind, "tube_mm": self.tube_mm, "ring_mm": self.ring_mm, "side": self.side}

"""The extended model: the base geometry plus a list of effect components, with unique parameter names."""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np
from metrology.core.effects.base import Covariates


@dataclass(frozen=True)
class ExtendedModel:
    """The base geometry plus a list of components.

    Attributes
    ----------
    layout : SensorLayout, the sensors' zero points and directions (TCS)
    components : tuple of Component
    """

    layout: object
    components: tuple = ()

    def __post_init__(self):
        seen = set()
        for c in self.components:
            for pn in c.full_param_names:
                if pn in seen:
                    raise ValueError(f"parameter name clash: {pn} appears in two components")
                seen.add(pn)
        object.__setattr__(self, "components", tuple(self.components))

    @property
    def param_names(self) -> tuple:
        return tuple(pn for c in self.components for pn in c.full_param_names)

    def terms(self, d0, cov: Covariates):
        """``(p, n)`` mm: the sum of the components' terms."""
        out = np.zeros_like(d0)
        for c in self.components:
            out = out + c.evaluate(c.values, d0, cov)
        return out

    def predict(self, normal_tcs, offset_tcs, cov: Covariates):
        """Readings ``(p, n)`` mm of the extended model on planes ``(p, 3)``, ``(p,)`` in the TCS."""
        from metrology.core.model import readings

        d0, _ = readings(self.layout.zero, self.layout.direction, normal_tcs, offset_tcs)
        return d0 + self.terms(d0, cov)

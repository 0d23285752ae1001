"""The catalogue of physical effects that extend the measurement model, as components, and
its one registry.

Adding an effect is one :class:`Component` subclass (its ``evaluate``/``basis``, and its
registry entry: ``per_sensor``, ``advice``, ``plot_variable``, ``size_meaning``,
``candidates``, ``hidden``) and one line in :data:`REGISTRY`. The candidates of a diagnosis,
its advice, its figures, the simulator and the CLI all read the registry.
"""

from metrology.core.effects.base import REFERENCE_TEMP_C, SECONDS_PER_HOUR, VERDICTS, Component, Covariates
from metrology.core.effects.model import ExtendedModel
from metrology.core.effects.sensor import Drift, Incidence, Nonlinearity, Scale
from metrology.core.effects.setup import Outliers, PlaneForm, PoseError

#: name -> component class, in the order candidates are tried (per sensor first, then the set-up)
REGISTRY = {cls.name: cls for cls in (Scale, Incidence, Nonlinearity, Drift, PlaneForm, PoseError, Outliers)}
#: names of the catalogued effects (the ``cause`` of a diagnosis); the two verdicts are ``VERDICTS``
CATALOGUE = tuple(REGISTRY)

__all__ = [
    "Covariates", "Component", "Scale", "Incidence", "Drift", "Nonlinearity", "PlaneForm", "PoseError",
    "Outliers", "ExtendedModel", "REGISTRY", "CATALOGUE", "VERDICTS", "SECONDS_PER_HOUR", "REFERENCE_TEMP_C",
]

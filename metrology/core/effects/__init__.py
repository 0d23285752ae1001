"""The catalogue of physical effects that extend the measurement model, as components.

The base model of :mod:`metrology.core.model` predicts a reading ``d0`` from the sensor's zero
point and beam direction and the datum plane in the pose's TCS. Each effect is a small
named component that adds a term to it::

    d = d0(theta) + sum_c f_c(values_c; d0, covariates)                     (mm)

A component has named parameters, a pure :meth:`Component.evaluate` (the additive term,
``(p, n)`` mm, zero on sensors it does not concern), an analytic :meth:`Component.jacobian`
(``(p, n, k)``) and, when the term depends on ``d0``, its derivative ``df/dd0`` (so the
Jacobian of the full model w.r.t. the base parameters is ``(1 + sum df/dd0) J0``).
A :class:`ExtendedModel` is the base geometry plus a list of components; parameter names are
``<component>.<sensor>.<param>`` and a clash raises. The same components drive the simulator
(:mod:`metrology.sim.synth`) and the extended fit (:mod:`metrology.diagnosis.fit`).

Catalogue (formulas with ``gamma`` the beam's incidence angle on the datum, ``N.u`` the cosine
between the TCS plane normal and the beam, ``x = (2 d0 - lo - hi) / (hi - lo)`` the reading
normalised over the sensor's range ``[lo, hi]``):

``scale``        ``k d0``                         gain error of the sensor (unitless ``k``)
``incidence``    ``c tan^2(gamma)``               spot/speckle bias growing with tilt (``c`` mm)
``drift``        ``r (T - 20 C)`` or ``r t``      thermal zero drift (mm/K or mm/h)
``nonlinearity`` ``c2 P2(x) + c3 P3(x)``          linearity error: bow and S-shape (mm)
``plane_form``   ``w(s, t) / (N.u)``, ``w = b_s s + b_t t + b_ss s^2 + b_st s t + b_tt t^2``,
                 ``(s, t)`` the spot's in-plane coordinates on the datum (tracker frame) over
                 ``R``: datum tilt, bow and twist (mm at ``R`` from the datum centre)
``pose_error``   ``e_p / (N.u)``                  TCS position error along the datum normal, one
                 number per pose (mm; gauge ``sum e_p = 0``)
``outliers``     ``g_j`` on flagged readings      gross readings (mm), equivalent to dropping them
``shift``        ``s H(t - t_k)``                 a knocked sensor: its zero jumps at a pose the data
                 locate (change-point search in time order) and stays (mm)

A constant term is absorbed by the zero point along the beam (an exact degeneracy: moving
``E`` by ``delta u`` changes every reading by ``-delta``), so components carry no constant.
The covariates ``gamma``, ``N.u`` and the spot position are evaluated at the base
calibration and held fixed in the extended fit (their dependence on the tilt parameters is
second order: a product of two small numbers); ``d0`` is live.

The registry
------------
:data:`REGISTRY` maps each effect's name to its :class:`Component` subclass, in the order the
diagnosis builds and scores its candidates. One entry holds everything a consumer reads:
``name``, ``param_names``/``param_units``, the term (``basis``/``evaluate``/``jacobian``),
``advice`` (the poses that separate it), ``size_meaning`` (the simulator's ``size``),
``plot_key`` (the covariate of its residual plot), ``plot_term`` (draw the fitted term),
``key_params`` (what the report compares), ``setup`` (an effect of the set-up, no sensor),
``candidates_for_sensor``/``candidates_for_setup`` (the diagnosis' candidates) and ``hidden``
(the simulator's component). Adding an effect is one class and one entry here.
"""

from __future__ import annotations

from metrology.core.effects.base import REFERENCE_TEMP_C, SECONDS_PER_HOUR, VERDICTS, Component, Covariates
from metrology.core.effects.model import ExtendedModel
from metrology.core.effects.characteristic import Nonlinearity, Scale
from metrology.core.effects.sensor import Drift, Incidence
from metrology.core.effects.setup import Outliers, PlaneForm, PoseError
from metrology.core.effects.shift import Shift

__all__ = [
    "Covariates",
    "Component",
    "Scale",
    "Incidence",
    "Drift",
    "Nonlinearity",
    "PlaneForm",
    "PoseError",
    "Outliers",
    "Shift",
    "ExtendedModel",
    "REGISTRY",
    "CATALOGUE",
    "VERDICTS",
    "SECONDS_PER_HOUR",
    "REFERENCE_TEMP_C",
]

#: the effect catalogue: name -> Component subclass (the order candidates are built and scored)
REGISTRY = {cls.name: cls for cls in (Scale, Incidence, Nonlinearity, Drift, PlaneForm, PoseError, Outliers,
                                          Shift)}
#: names of the catalogued effects (the ``cause`` of a diagnosis)
CATALOGUE = tuple(REGISTRY)

"""``simulate-log --controller metro`` with an extended layout: the cell's controller
(metrology.measure.surface_normal) applies the layout's terms, the temperature coefficient with the
head's temperature the forward simulator logs (metrology.sim.forward.log: ``wants_temperature``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.core.effects import Drift
from metrology.core.effects.terms import HeadTerms
from metrology.core.layout import SensorLayout
from metrology.core.paper import table6_layouts
from metrology.jobs.simulate_log import metro_controller
from metrology.sim.forward import HeadProperties, LogSpec, SensorProperty, make_panel
from metrology.sim.forward.log import simulate_cell

RATE, REF = 0.02, 20.0  # a large coefficient (20 um/K, +-3 K: +-60 um on L3) so one batch shows it


def test_the_metro_controller_applies_a_temperature_coefficient_to_the_drilled_angle():
    nom, _ = table6_layouts()
    simple = SensorLayout(nom.names, nom.zero, nom.direction, [0.003] * 4, [[20, 80]] * 4,
                          covariance=np.diag(np.tile([1e-6] * 3 + [1e-8] * 2, 4)))
    term = Drift((2,), [RATE], np.array([1e-4]), nom.names, variable="temp", ref=REF)
    ext = replace(simple, effects=HeadTerms((term,), [[1e-10]], np.zeros((20, 1))))
    props = HeadProperties((SensorProperty(2, tempco_mm_per_k=RATE, ref_temp_c=REF),))
    after = {}
    for name, cell in (("simple", simple), ("extended", ext)):
        spec = LogSpec(simple, cell, make_panel("flat"), temperature_c=(20.0, 3.0, 0.05), properties=props,
                       controller=metro_controller(), start_time_s=6 * 3600.0)
        ch = next(simulate_cell(spec, 7, 0, 600, chunk_holes=600))
        assert ch.adjusted.mean() > 0.99
        after[name] = float(np.median(np.degrees(ch.true_after)))
    assert after["extended"] < 0.5 * after["simple"]

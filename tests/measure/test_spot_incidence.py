"""An incidence term on a curved panel with the panel known: each beam's incidence at its own spot
(metrology.core.effects.apply.spot_incidence), as the forward simulator's physics has it (the true
surface's normal at the spot), not the hole's plane's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from metrology.core.effects import Incidence
from metrology.core.effects.terms import HeadTerms


def test_the_incidence_at_each_spot_of_a_cylinder_takes_the_term_off():
    from metrology.core.effects.apply import remove_terms
    from metrology.jobs.measure_panel import footprint_mm, panel_hole_surfaces
    from metrology.measure.panel import HoleTable
    from metrology.measure.placement import place
    from metrology.panel.mesh import Panel
    from metrology.sim.forward import LogSpec, draw_head, make_panel, simulate_log
    from metrology.sim.forward.log_write import log_table
    from metrology.sim.head_terms import properties_from_terms
    from tests.measure.panel_fixtures import panel_mesh

    head = draw_head(np.random.default_rng(91), 4, noise_mm=0.004)
    lay = head.true
    ext = replace(lay, effects=HeadTerms((Incidence((3,), [0.25], np.array([1e-3]), lay.names),), np.eye(1) * 1e-6,
                                         np.zeros((20, 1))))
    surface = make_panel("cylinder", 500.0)
    chunks = {}
    for name, props in (("plain", None), ("with", properties_from_terms(ext))):
        spec = LogSpec(lay, lay, surface, noise_mm=1e-7, temperature_c=(20.0, 0.0, 0.0), standoff_mm=45.0,
                       properties=props)
        (chunks[name],) = simulate_log(spec, 5, 300)
    ch, plain = chunks["with"], chunks["plain"].d
    table = log_table(ch)
    P = ch.drill_point
    surf = panel_hole_surfaces(Panel(panel_mesh(surface)), HoleTable(tuple(map(str, table.column("hole_id").to_pylist())),
                                                                   P, -surface.normal_at(P), "holes"),
                               footprint_mm(lay), 0.5, 0.0, 0.0)
    shape = place(surf, table, lay).shape
    term = np.nanmax(np.abs(ch.d - plain)[:, 3])
    flat = np.nanmax(np.abs(remove_terms(ext, ch.d).d - plain)[:, 3])  # the hole's plane's incidence
    spot = np.nanmax(np.abs(remove_terms(ext, ch.d, shape=shape).d - plain)[:, 3])
    # measured: a 42 um term, 9.4 um left by the plane's incidence, 1.2 um by each spot's (its plane from the raw
    # readings, the shape square to the axis: first order)
    assert term > 0.02 and flat > 0.1 * term  # the plane misses the spot's own incidence by a fifth of the term
    assert spot < 0.05 * term and spot < 0.25 * flat, (term, flat, spot)

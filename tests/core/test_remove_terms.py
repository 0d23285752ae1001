"""The one implementation that removes a layout's head terms from production readings
(metrology.core.effects.apply.remove_terms): ``metro measure`` (measure.effects.apply_terms) and
``metro normals`` (panel.head_terms.corrected) both call it. Readings from the forward simulator
(metrology.sim.forward) drawing the head with the terms' physics (metrology.sim.head_terms)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from metrology.core.effects import Incidence, Scale
from metrology.core.effects.terms import HeadTerms


@pytest.fixture(scope="module")
def logs():
    from metrology.sim.forward import LogSpec, draw_head, make_panel, simulate_log
    from metrology.sim.head_terms import properties_from_terms

    head = draw_head(np.random.default_rng(7), 4, noise_mm=0.004)
    lay = replace(head.true, covariance=np.eye(20) * 1e-8)
    names = lay.names
    comps = (Incidence((1,), [0.06], np.array([1e-3]), names), Scale((3,), [0.008], np.array([1e-4]), names))
    ext = replace(lay, effects=HeadTerms(comps, np.diag([1e-6, 1e-8]), np.zeros((20, 2))))
    out = {}
    for name, props in (("plain", None), ("with", properties_from_terms(ext))):
        spec = LogSpec(head.true, lay, make_panel("flat", None), noise_mm=1e-7, temperature_c=(20.0, 0.0, 0.0),
                       standoff_mm=45.0, properties=props)
        (out[name],) = simulate_log(spec, 11, 400)
    return ext, out["plain"].d, out["with"].d


def test_the_terms_come_off_to_the_simulators_effect_free_readings(logs):
    from metrology.core.effects.apply import remove_terms

    ext, plain, d = logs
    assert np.nanmax(np.abs(d - plain)) > 0.02  # the terms are there (a 60 um incidence response, a 0.8 % gain)
    got = remove_terms(ext, d).d
    # within 1 um: the incidence is taken from the raw readings' plane, which the 0.37 mm gain tilts
    np.testing.assert_allclose(got, plain, rtol=0, atol=1e-3)
    assert np.nanmax(np.abs(got - plain)[:, 1]) < 0.05 * np.nanmax(np.abs(d - plain)[:, 1])


def test_a_missing_reading_leaves_the_incidence_to_the_other_three(logs):
    """3 of 4 readings: the incidence from their plane, the term-bearing readings still corrected."""
    from metrology.core.effects.apply import remove_terms

    ext, plain, d = logs
    d3 = d.copy()
    d3[:, 2] = np.nan
    got = remove_terms(ext, d3).d
    assert np.all(np.isnan(got[:, 2]))
    np.testing.assert_allclose(got[:, [0, 1, 3]], plain[:, [0, 1, 3]], rtol=0, atol=1e-3)


def test_where_the_incidence_is_not_known_the_term_bearing_readings_are_blanked(logs):
    """2 of 4 readings make no plane: the incidence term's sensor (L2) blanked, never corrected at normal
    incidence; a sensor without a term keeps its reading; a gain (no covariate) is still removed."""
    from metrology.core.effects.apply import UNKNOWN_COVARIATE, remove_terms

    assert UNKNOWN_COVARIATE == "blank"
    ext, plain, d = logs
    d2 = d.copy()
    d2[:, [0, 2]] = np.nan  # L2 (incidence) and L4 (gain) left
    got = remove_terms(ext, d2).d
    assert np.all(np.isnan(got[:, 1]))
    np.testing.assert_allclose(got[:, 3], plain[:, 3], rtol=0, atol=1e-3)
    d2 = d.copy()
    d2[:, [1, 2]] = np.nan  # L1 (no term) and L4 (gain) left
    got = remove_terms(ext, d2).d
    np.testing.assert_array_equal(got[:, 0], d[:, 0])
    np.testing.assert_allclose(got[:, 3], plain[:, 3], rtol=0, atol=1e-3)


def test_measure_and_normals_remove_the_terms_by_the_same_implementation(logs):
    from metrology.measure.effects import apply_terms
    from metrology.panel.head_terms import corrected

    ext, _, d = logs
    mixed = d.copy()
    mixed[::3, 0] = np.nan  # 3 readings: the plane of the others
    mixed[1::7, [0, 2]] = np.nan  # 2 readings: no incidence
    a = apply_terms(ext, mixed).d
    np.testing.assert_array_equal(corrected(ext, mixed), a)
    assert np.isnan(a[1, 1]) and np.isfinite(a[3, 1])
    assert corrected(replace(ext, effects=None), mixed) is mixed

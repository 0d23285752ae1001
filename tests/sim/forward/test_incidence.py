"""Incidence bias: even in the angle, sized at the largest angle seen."""

import numpy as np
import pytest

from metrology.sim.forward import IncidenceBias, draw_incidence


@pytest.mark.parametrize("shape", ["one_minus_cos", "quadratic", "even_poly"])
def test_bias_is_even_zero_at_normal_and_sized_at_the_largest_angle(shape, rng):
    for _ in range(5):
        amax = rng.uniform(0.2, 0.8)
        b = draw_incidence(rng, amax, 0.05, shape)
        a = rng.uniform(0, amax, 50)
        assert np.allclose(b(a), b(-a), rtol=1e-14, atol=0)
        assert np.max(np.abs(b(a))) > 0
        assert b(0.0) == 0.0
        assert abs(float(b(amax))) == pytest.approx(0.05, rel=1e-12)
        v = b(np.linspace(0, amax, 200))
        assert np.all(np.abs(v) <= 0.05 * (1 + 1e-12))  # monotone in |a| for these shapes


def test_known_values():
    assert IncidenceBias("quadratic", {"k_mm": 0.1})(0.5) == pytest.approx(0.025)
    assert IncidenceBias("one_minus_cos", {"k_mm": 0.2})(np.pi / 3) == pytest.approx(0.1)
    assert IncidenceBias("even_poly", {"coeffs_mm": [1.0, 2.0]})(0.5) == pytest.approx(0.25 + 2 * 0.0625)

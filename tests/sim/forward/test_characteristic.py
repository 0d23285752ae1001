"""Reading-error curves against distance."""

import numpy as np
import pytest

from metrology.sim.forward import Characteristic, draw_curve

SHAPES = ["gain", "table", "s_curve", "tanh"]


@pytest.mark.parametrize("shape", SHAPES)
def test_size_is_the_peak_to_valley_over_the_range(shape, rng):
    for size in (0.02, 0.15):
        c = draw_curve(rng, shape, 30.0, 70.0, size)
        e = c(np.linspace(30, 70, 2001))
        assert np.ptp(e) == pytest.approx(size, rel=1e-3)


def test_table_passes_through_its_knots(rng):
    for _ in range(10):
        c = draw_curve(rng, "table", 30.0, 70.0, 0.1)
        k, v = np.array(c.params["knots_mm"]), np.array(c.params["values_mm"])
        assert len(k) >= 4 and k[0] == 30.0 and k[-1] == 70.0
        assert np.allclose(c(k), v, atol=1e-15)


def test_table_is_monotone_between_monotone_knots():
    c = Characteristic("table", 30.0, 70.0, {"knots_mm": [30, 40, 55, 70], "values_mm": [0.0, 0.01, 0.05, 0.06]})
    e = c(np.linspace(30, 70, 1001))
    assert np.all(np.diff(e) >= -1e-15)


def test_gain_is_proportional_to_distance(rng):
    c = draw_curve(rng, "gain", 30.0, 70.0, 0.08)
    d = np.array([30.0, 45.0, 70.0])
    assert np.allclose(c(d) / d, c.params["gain"]) and abs(c.params["gain"]) == pytest.approx(0.08 / 40)


def test_s_curve_is_linear_at_one_end_and_flat_at_the_other(rng):
    for _ in range(6):
        c = draw_curve(rng, "s_curve", 30.0, 70.0, 0.1)
        d = np.linspace(30, 70, 4001)
        slope = np.gradient(c(d), d)
        ends = np.abs([slope[:50].mean(), slope[-50:].mean()])
        assert ends.min() < 0.15 * ends.max()  # one end flattens
        assert ends.max() > 0.5 * 0.1 / 40  # the other keeps a linear part


def test_unknown_shape_is_refused(rng):
    with pytest.raises(ValueError, match="characteristic shape"):
        draw_curve(rng, "wiggle", 30.0, 70.0, 0.1)

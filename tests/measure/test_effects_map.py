"""The terms' share of U95 (measure/effects.effects_slope_cov) moves the slopes by the estimator's own map: a
reading's change of one sensor of a head whose sensors' noise differs (so the micro-plane weighs them unequally)
changes the fitted slopes (measure/estimator.fit_tilt) as the effects source says, sensor by sensor."""

from dataclasses import replace

import numpy as np

from metrology.io.data import data_path
from metrology.io.layout import load_layout
from metrology.measure.effects import effects_slope_cov
from metrology.measure.estimator import fit_tilt


def test_the_effects_source_moves_the_slopes_as_the_weighted_fit_does():
    lay = load_layout(data_path("measured", "nominal.toml"))
    lay = replace(lay, noise_mm=np.array([0.004, 0.004, 0.004, 0.012]))  # L4 three times noisier: weighed down
    rng = np.random.default_rng(7)
    # five holes on planes tilted up to 2 deg: each beam's reading where it meets the plane (the map is first order
    # in the reading; the unweighted map is off by up to 2x on this head)
    E, u = lay.zero, lay.direction
    ab = rng.uniform(-0.035, 0.035, size=(5, 2))
    z0 = E[:, 2].mean() + 50.0 * u[:, 2].mean()
    a, b = ab[:, :1], ab[:, 1:]
    d = (z0 + a * E[:, 0] + b * E[:, 1] - E[:, 2]) / (u[:, 2] - a * u[:, 0] - b * u[:, 1])
    base = fit_tilt(lay, d)
    s = 0.002  # mm: one term's standard uncertainty, a reading offset of one sensor
    delta = 1e-4
    for i in range(lay.n):
        jac = np.zeros((len(d), lay.n, 1))
        jac[:, i, 0] = 1.0  # the term moves sensor i's reading 1 mm per unit
        (c00, c01, c11), _ = effects_slope_cov(lay, d, base.normal, jac, np.array([[s * s]]), np.zeros((1, 5 * lay.n)))
        moved = d.copy()
        moved[:, i] += delta
        dg = (fit_tilt(lay, moved).g - base.g) / delta * s  # the slopes' change for one sigma of the term
        np.testing.assert_allclose(c00, dg[:, 0] ** 2, rtol=1e-3, atol=1e-16, err_msg=f"L{i + 1}")
        np.testing.assert_allclose(c11, dg[:, 1] ** 2, rtol=1e-3, atol=1e-16, err_msg=f"L{i + 1}")
        np.testing.assert_allclose(c01, dg[:, 0] * dg[:, 1], rtol=1e-3, atol=1e-16, err_msg=f"L{i + 1}")

"""Gross readings, blanks, cross-talk, periodic error and noise."""

import numpy as np

from metrology.sim.forward.errors import add_blanks, add_gross, add_noise, crosstalk_offset, periodic_offset


def test_gross_readings_are_few_and_0p1_to_2_mm_off(rng):
    d = rng.uniform(30, 70, (100, 4))
    g, hits = add_gross(rng, d, 5)
    changed = np.argwhere(g != d)
    assert len(changed) == 5 == len(hits)
    delta = (g - d)[g != d]
    assert np.all((np.abs(delta) >= 0.1) & (np.abs(delta) <= 2.0))
    assert sorted(map(tuple, changed.tolist())) == sorted((i, j) for i, j, _ in hits)


def test_blanks_are_nan(rng):
    d = rng.uniform(30, 70, (50, 3))
    b, cells = add_blanks(rng, d, 3)
    assert np.isnan(b).sum() == 3 and all(np.isnan(b[i, j]) for i, j in cells)


def test_noise_has_its_stated_sigma(rng):
    d = np.full((20000, 3), 50.0)
    r = add_noise(rng, d, [0.003, 0.005, 0.010]) - d
    sd = r.std(axis=0)
    assert np.allclose(sd, [0.003, 0.005, 0.010], rtol=5 / np.sqrt(2 * 20000))


def test_crosstalk_is_proportional_and_periodic_is_periodic():
    src = np.array([40.0, 45.0, 50.0, 60.0])
    assert np.allclose(crosstalk_offset(src, 0.002), 0.002 * (src - src.mean()))
    x = np.arange(40.0)
    p = periodic_offset(x, 0.03, 8.0, 0.4)
    assert np.allclose(p[:-8], p[8:]) and np.max(np.abs(p)) <= 0.03

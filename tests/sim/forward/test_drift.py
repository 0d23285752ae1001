"""Time stamps, temperature profiles, drift and the first-order lag."""

import numpy as np
import pytest

from metrology.sim.forward import Drift, TemperatureProfile, draw_drift, draw_temperature, draw_times
from metrology.sim.forward.drift import lagged


def _monotone(x):
    dx = np.diff(x)
    return np.all(dx >= 0) or np.all(dx <= 0)


@pytest.mark.parametrize("shape", ["warm_cool", "hvac"])
def test_some_profiles_are_not_monotonic(shape, rng):
    for _ in range(5):
        t = draw_times(rng, 100)
        prof = draw_temperature(rng, t[-1], shape)
        assert not _monotone(prof(t))


def test_times_increase(rng):
    t = draw_times(rng, 150)
    assert t[0] == 0 and np.all(np.diff(t) >= 15)


@pytest.mark.parametrize("shape", ["time_warmup", "temperature", "temperature_lag"])
def test_drift_size_is_its_peak_to_valley(shape, rng):
    t = draw_times(rng, 80)
    temp = draw_temperature(rng, t[-1], "warm_cool")(t)
    dr = draw_drift(rng, t, temp, 0.07, shape)
    off = dr.offset(t, temp)
    assert np.ptp(off) == pytest.approx(0.07, rel=1e-12)
    assert off[0] == pytest.approx(0.0, abs=1e-15)


def test_temperature_drift_follows_the_temperature():
    t = np.linspace(0, 3600, 50)
    temp = TemperatureProfile("hvac", {"T0": 21.0, "A": 1.0, "P": 1200.0, "phi": 0.0, "slope": 0.0})(t)
    off = Drift("temperature", {"k_mm": 0.01, "tau_lag_s": 0.0}).offset(t, temp)
    assert np.allclose(off, 0.01 * (temp - temp[0]))


def test_lag_against_an_ode_solver(rng):
    from scipy.integrate import solve_ivp

    t = np.sort(np.concatenate([[0.0], rng.uniform(0, 5000, 60)]))
    temp = 21 + np.sin(t / 600.0) + 0.3 * rng.normal(size=t.size)
    tau = 400.0
    sol = solve_ivp(lambda x, y: (np.interp(x, t, temp) - y) / tau, (0, t[-1]), [temp[0]], t_eval=t,
                    rtol=1e-10, atol=1e-12, max_step=5.0)
    assert np.allclose(lagged(t, temp, tau), sol.y[0], atol=1e-6)
    assert not np.allclose(lagged(t, temp, tau), temp, atol=1e-2)

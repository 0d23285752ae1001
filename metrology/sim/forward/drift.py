"""Time stamps, temperature histories and sensor drift.

Time ``t`` is in s from the first pose, temperature ``T`` in deg C at the sensor head.

Temperature profiles (``temperature(t)``, deg C):

- ``warmup``: ``T0 + dT (1 - exp(-t / tau))``;
- ``warm_cool``: the warm-up, then from ``t_c`` a cool-down ``- dT2 (1 - exp(-(t - t_c) / tau2))``
  (not monotonic);
- ``hvac``: ``T0 + A sin(2 pi t / P + phi) + slope t`` (an air-conditioning cycle; not monotonic).

Drift of one sensor (its reading offset, mm, added to every reading at that time):

- ``time_warmup``: ``k (1 - exp(-t / tau))``, the electronics warming up, whatever the air does;
- ``temperature``: ``k (T_s(t) - T_s(0))``, with ``T_s`` the head temperature seen through a
  first-order lag ``tau_lag dT_s/dt = T - T_s`` of time constant ``tau_lag`` s (``tau_lag = 0`` is no
  lag), solved exactly for ``T`` linear between time stamps.

``draw_drift`` scales ``k`` so the offset's peak-to-valley over the run is the size (mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["TemperatureProfile", "Drift", "draw_times", "draw_temperature", "draw_drift",
           "PROFILE_SHAPES", "DRIFT_SHAPES", "lagged"]

PROFILE_SHAPES = ("warmup", "warm_cool", "hvac")
DRIFT_SHAPES = ("time_warmup", "temperature", "temperature_lag")


@dataclass(frozen=True)
class TemperatureProfile:
    """A head-temperature history ``T(t)`` deg C, ``t`` s (see the module docstring)."""

    shape: str
    params: dict = field(default_factory=dict)

    def __call__(self, t):
        t = np.asarray(t, float)
        p = self.params
        if self.shape == "warmup":
            return p["T0"] + p["dT"] * (1 - np.exp(-t / p["tau"]))
        if self.shape == "warm_cool":
            up = p["T0"] + p["dT"] * (1 - np.exp(-t / p["tau"]))
            tc = np.clip(t - p["t_c"], 0.0, None)
            return up - p["dT2"] * (1 - np.exp(-tc / p["tau2"]))
        if self.shape == "hvac":
            return p["T0"] + p["A"] * np.sin(2 * np.pi * t / p["P"] + p["phi"]) + p["slope"] * t
        raise ValueError(f"temperature profile must be one of {PROFILE_SHAPES}, got {self.shape!r}")

    def to_dict(self) -> dict:
        return {"shape": self.shape, **self.params}


def lagged(t, temp, tau_s: float):
    """First-order lag ``tau dy/dt = T - y``, ``y(0) = T(0)``, at samples ``t (p,)`` s of ``temp (p,)``,
    exact for ``T`` linear between samples: over a step ``h`` with slope ``r``,
    ``y1 = T1 - r tau + (y0 - T0 + r tau) exp(-h / tau)``."""
    t = np.asarray(t, float)
    temp = np.asarray(temp, float)
    if tau_s <= 0:
        return temp.copy()
    y = np.empty_like(temp)
    y[0] = temp[0]
    for k in range(1, len(t)):
        h = t[k] - t[k - 1]
        a = np.exp(-h / tau_s)
        r = (temp[k] - temp[k - 1]) / h
        y[k] = temp[k] - r * tau_s + (y[k - 1] - temp[k - 1] + r * tau_s) * a
    return y


@dataclass(frozen=True)
class Drift:
    """A reading offset of one sensor against time/temperature (see the module docstring).

    Attributes
    ----------
    shape : str, one of ``DRIFT_SHAPES``
    params : dict: ``k_mm`` (mm, or mm per deg C for temperature shapes), ``tau_s``, ``tau_lag_s``
    """

    shape: str
    params: dict = field(default_factory=dict)

    def offset(self, t, temp):
        """Offset mm ``(p,)`` at times ``t (p,)`` s with head temperatures ``temp (p,)`` deg C."""
        t = np.asarray(t, float)
        p = self.params
        if self.shape == "time_warmup":
            return p["k_mm"] * (1 - np.exp(-t / p["tau_s"]))
        if self.shape in ("temperature", "temperature_lag"):
            y = lagged(t, temp, p.get("tau_lag_s", 0.0))
            return p["k_mm"] * (y - y[0])
        raise ValueError(f"drift shape must be one of {DRIFT_SHAPES}, got {self.shape!r}")

    def to_dict(self) -> dict:
        return {"shape": self.shape, **self.params}


def draw_times(rng: np.random.Generator, n_poses: int):
    """Time stamps ``(p,)`` s: 15-60 s between poses, with a few pauses of 2-10 min."""
    dt = rng.uniform(15.0, 60.0, n_poses - 1)
    pauses = rng.random(n_poses - 1) < 0.03
    dt = dt + pauses * rng.uniform(120.0, 600.0, n_poses - 1)
    return np.concatenate([[0.0], np.cumsum(dt)])


def draw_temperature(rng: np.random.Generator, t_end_s: float, shape: str | None = None) -> TemperatureProfile:
    """A random profile over ``[0, t_end_s]``: 20-23 deg C start, changes of 0.5-4 deg C."""
    shape = shape or PROFILE_SHAPES[int(rng.integers(len(PROFILE_SHAPES)))]
    T0 = float(rng.uniform(20.0, 23.0))
    if shape == "warmup":
        p = {"T0": T0, "dT": float(rng.uniform(0.5, 4.0)), "tau": float(rng.uniform(0.1, 0.5) * t_end_s)}
    elif shape == "warm_cool":
        dT = float(rng.uniform(1.0, 4.0))
        p = {"T0": T0, "dT": dT, "tau": float(rng.uniform(0.05, 0.2) * t_end_s),
             "t_c": float(rng.uniform(0.35, 0.65) * t_end_s), "dT2": float(rng.uniform(0.5, 1.0) * dT),
             "tau2": float(rng.uniform(0.05, 0.3) * t_end_s)}
    elif shape == "hvac":
        p = {"T0": T0, "A": float(rng.uniform(0.3, 1.5)), "P": float(rng.uniform(0.15, 0.5) * t_end_s),
             "phi": float(rng.uniform(0, 2 * np.pi)), "slope": float(rng.uniform(-1.0, 1.0) / t_end_s)}
    else:
        raise ValueError(f"temperature profile must be one of {PROFILE_SHAPES}, got {shape!r}")
    return TemperatureProfile(shape, p)


def draw_drift(rng: np.random.Generator, t, temp, size_mm: float, shape: str | None = None) -> Drift:
    """A random drift whose offset has peak-to-valley ``size_mm`` over the run ``t (p,)`` s, ``temp (p,)``."""
    shape = shape or DRIFT_SHAPES[int(rng.integers(len(DRIFT_SHAPES)))]
    t = np.asarray(t, float)
    sign = float(rng.choice([-1.0, 1.0]))
    if shape == "time_warmup":
        p = {"k_mm": 1.0, "tau_s": float(rng.uniform(0.1, 0.5) * t[-1])}
    elif shape == "temperature":
        p = {"k_mm": 1.0, "tau_lag_s": 0.0}
    elif shape == "temperature_lag":
        p = {"k_mm": 1.0, "tau_lag_s": float(rng.uniform(0.02, 0.15) * t[-1])}
    else:
        raise ValueError(f"drift shape must be one of {DRIFT_SHAPES}, got {shape!r}")
    raw = Drift(shape, p).offset(t, temp)
    ptp = float(np.ptp(raw))
    if ptp <= 0:
        raise ValueError("drift: the temperature history is constant, no temperature drift can be drawn")
    p["k_mm"] = sign * size_mm / ptp
    return Drift(shape, p)

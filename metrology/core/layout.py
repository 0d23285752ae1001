"""The sensor layout: zero points and beam directions of n >= 3 sensors, and its TOML file.

Schema (a public contract, see README "File formats")::

    units = "mm"
    [[sensors]]
    name = "L1"
    zero = [-36.4655, 36.4655, -35.0]        # mm, TCS
    direction = [0.3536, -0.3536, 0.8660]    # unit vector, TCS
    noise_mm = 0.003                          # reading repeatability, 1 sigma (optional)
    range_mm = [20.0, 80.0]                   # valid readings (optional)

A calibrated layout adds, per sensor, ``zero_stderr_mm`` (3 numbers), ``direction_stderr_deg``
(2 numbers: tilt about the chart axes e1, e2) and an optional ``[sensors.effects]`` table of
extra effect terms; files with these keys are read back unchanged.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace

import numpy as np

from metrology.io.atomic import write_text

__all__ = ["SensorLayout", "load_layout", "save_layout"]

#: direction vectors in a layout file must be unit within this (typed drawings round to
#: 4 decimals); they are then normalised exactly
DIRECTION_FILE_TOL = 2e-3


@dataclass(frozen=True)
class SensorLayout:
    """Zero points and beam directions of the sensors on the pressure foot.

    Attributes
    ----------
    names : tuple of str, length n
    zero : (n, 3) float, mm, TCS
    direction : (n, 3) float, unit, TCS
    noise_mm : (n,) float, mm, 1 sigma reading repeatability; NaN where not stated
    range_mm : (n, 2) float, mm, valid reading interval; (-inf, inf) where not stated
    zero_stderr_mm : (n, 3) float, mm, or None (a nominal layout)
    direction_stderr_deg : (n, 2) float, deg, or None
    effects : dict of sensor name -> dict of effect-term name -> float
    """

    names: tuple
    zero: np.ndarray
    direction: np.ndarray
    noise_mm: np.ndarray | None = None
    range_mm: np.ndarray | None = None
    zero_stderr_mm: np.ndarray | None = None
    direction_stderr_deg: np.ndarray | None = None
    effects: dict = field(default_factory=dict)

    def __post_init__(self):
        n = len(self.names)
        zero = np.asarray(self.zero, dtype=float).reshape(n, 3)
        direction = np.asarray(self.direction, dtype=float).reshape(n, 3)
        if n < 3:
            raise ValueError(f"a layout needs at least 3 sensors, got {n}")
        if len(set(self.names)) != n:
            raise ValueError(f"sensor names must be unique, got {list(self.names)}")
        if not (np.all(np.isfinite(zero)) and np.all(np.isfinite(direction))):
            raise ValueError("layout zero points and directions must be finite")
        norms = np.linalg.norm(direction, axis=1)
        if np.any(norms == 0):
            raise ValueError("a beam direction is the zero vector")
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "zero", zero)
        object.__setattr__(self, "direction", direction / norms[:, None])
        noise = np.full(n, np.nan) if self.noise_mm is None else np.asarray(self.noise_mm, float).reshape(n)
        object.__setattr__(self, "noise_mm", noise)
        rng = np.tile([-np.inf, np.inf], (n, 1)) if self.range_mm is None else np.asarray(self.range_mm, float).reshape(n, 2)
        object.__setattr__(self, "range_mm", rng)

    @property
    def n(self) -> int:
        return len(self.names)

    def with_params(self, zero, direction, **kw) -> "SensorLayout":
        """A copy with new zero points ``(n, 3)`` mm and directions ``(n, 3)`` (normalised)."""
        return replace(self, zero=np.asarray(zero, float), direction=np.asarray(direction, float), **kw)

    def subset(self, names) -> "SensorLayout":
        idx = [self.names.index(nm) for nm in names]
        return SensorLayout(
            tuple(names), self.zero[idx], self.direction[idx], self.noise_mm[idx], self.range_mm[idx],
            None if self.zero_stderr_mm is None else self.zero_stderr_mm[idx],
            None if self.direction_stderr_deg is None else self.direction_stderr_deg[idx],
            {k: v for k, v in self.effects.items() if k in names},
        )


def _vec(path, i, key, value, length):
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: sensor {i + 1} '{key}' must be {length} numbers, got {value!r}") from None
    if arr.shape != (length,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{path}: sensor {i + 1} '{key}' must be {length} finite numbers, got {value!r}")
    return arr


def load_layout(path) -> SensorLayout:
    """Read a layout TOML file (see the module docstring); errors name the file and key."""
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except OSError as exc:
        raise ValueError(f"{path}: cannot read layout ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    units = data.get("units", "mm")
    if units != "mm":
        raise ValueError(f"{path}: units must be \"mm\", got {units!r}")
    sensors = data.get("sensors")
    if not isinstance(sensors, list) or len(sensors) < 3:
        raise ValueError(f"{path}: need a [[sensors]] array of at least 3 sensors, got {0 if not isinstance(sensors, list) else len(sensors)}")
    names, zero, direction, noise, rng, zse, dse, effects = [], [], [], [], [], [], [], {}
    for i, s in enumerate(sensors):
        name = s.get("name")
        if not isinstance(name, str) or not name or "," in name:
            raise ValueError(f"{path}: sensor {i + 1} needs a 'name' string without commas, got {name!r}")
        names.append(name)
        for key in ("zero", "direction"):
            if key not in s:
                raise ValueError(f"{path}: sensor {name} lacks '{key}'")
        zero.append(_vec(path, i, "zero", s["zero"], 3))
        u = _vec(path, i, "direction", s["direction"], 3)
        if abs(np.linalg.norm(u) - 1.0) > DIRECTION_FILE_TOL:
            raise ValueError(f"{path}: sensor {name} direction {u.tolist()} has norm {np.linalg.norm(u):.6f}, expected a unit vector")
        direction.append(u)
        nz = s.get("noise_mm", math.nan)
        if not isinstance(nz, (int, float)) or not (math.isnan(nz) or nz > 0):
            raise ValueError(f"{path}: sensor {name} noise_mm must be a positive number, got {nz!r}")
        noise.append(float(nz))
        r = _vec(path, i, "range_mm", s["range_mm"], 2) if "range_mm" in s else np.array([-np.inf, np.inf])
        if r[0] >= r[1]:
            raise ValueError(f"{path}: sensor {name} range_mm must be [min, max] with min < max, got {r.tolist()}")
        rng.append(r)
        zse.append(_vec(path, i, "zero_stderr_mm", s["zero_stderr_mm"], 3) if "zero_stderr_mm" in s else None)
        dse.append(_vec(path, i, "direction_stderr_deg", s["direction_stderr_deg"], 2) if "direction_stderr_deg" in s else None)
        if "effects" in s:
            if not isinstance(s["effects"], dict):
                raise ValueError(f"{path}: sensor {name} 'effects' must be a table")
            effects[name] = {k: float(v) for k, v in s["effects"].items()}
    zse_arr = None if any(z is None for z in zse) else np.array(zse)
    dse_arr = None if any(z is None for z in dse) else np.array(dse)
    return SensorLayout(tuple(names), np.array(zero), np.array(direction), np.array(noise), np.array(rng), zse_arr, dse_arr, effects)


def _fmt(values, digits=6):
    return "[" + ", ".join(f"{float(v):.{digits}f}" for v in np.atleast_1d(values)) + "]"


def layout_to_toml(layout: SensorLayout, header: str = "") -> str:
    """The TOML text of a layout (the schema :func:`load_layout` reads)."""
    lines = [f"# {line}" for line in header.splitlines()] + ['units = "mm"', ""]
    for i, name in enumerate(layout.names):
        lines += ["[[sensors]]", f'name = "{name}"', f"zero = {_fmt(layout.zero[i])}        # mm, TCS",
                  f"direction = {_fmt(layout.direction[i], 9)}    # unit vector, TCS"]
        if np.isfinite(layout.noise_mm[i]):
            lines.append(f"noise_mm = {layout.noise_mm[i]:.6g}")
        if np.all(np.isfinite(layout.range_mm[i])):
            lines.append(f"range_mm = {_fmt(layout.range_mm[i], 3)}")
        if layout.zero_stderr_mm is not None:
            lines.append(f"zero_stderr_mm = {_fmt(layout.zero_stderr_mm[i], 6)}")
        if layout.direction_stderr_deg is not None:
            lines.append(f"direction_stderr_deg = {_fmt(layout.direction_stderr_deg[i], 6)}")
        if layout.effects.get(name):
            lines.append("[sensors.effects]")
            lines += [f"{k} = {v:.9g}" for k, v in layout.effects[name].items()]
        lines.append("")
    return "\n".join(lines)


def save_layout(layout: SensorLayout, path, header: str = "") -> None:
    """Write ``layout`` to ``path`` atomically."""
    write_text(path, layout_to_toml(layout, header))

"""The sensor layout's TOML file: read (checked, one-line errors) and written (atomically, read back unchanged).

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
extra effect terms; files with these keys are read back unchanged. ``metro calibrate`` also
writes the calibration's full parameter covariance, which ``metro measure`` propagates::

    [calibration]
    parameters = ["L1.x", "L1.y", "L1.z", "L1.a", "L1.b", "L2.x", ...]   # 5 per sensor
    covariance = [[...], ...]     # (5n, 5n): mm for x y z (TCS), rad for a b

The calibration certificate's header fields (``metro calibrate --meta key=value``) are carried
in a table of strings::

    [certificate]
    part = "EE-7 pressure foot"
    operator = "J. Smith"

``a, b`` are the beam's tilts about the axes ``e1, e2`` of
:func:`metrology.core.model.direction_basis` of the file's own (calibrated) direction: the
direction is a unit vector, so of the six numbers of a sensor only these five are parameters.
"""

from __future__ import annotations

import json
import math
import tomllib
import numpy as np
from metrology.io.atomic import write_text
from metrology.core.layout import PARAMS_TANGENT, SensorLayout


#: direction vectors in a layout file must be unit within this (typed drawings round to
#: 4 decimals); they are then normalised exactly
DIRECTION_FILE_TOL = 2e-3


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
    except UnicodeDecodeError as exc:  # a binary file (a .ply, a .parquet) given for a layout
        raise ValueError(f"{path}: not a layout TOML file (not UTF-8 text: byte {exc.start}); expected the "
                         f"layout .toml of metro calibrate --out or the bundled nominal.toml") from None
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
    covariance = _covariance(path, data.get("calibration"), tuple(names))
    certificate = _certificate(path, data.get("certificate", {}))
    zse_arr = None if any(z is None for z in zse) else np.array(zse)
    dse_arr = None if any(z is None for z in dse) else np.array(dse)
    return SensorLayout(tuple(names), np.array(zero), np.array(direction), np.array(noise), np.array(rng), zse_arr, dse_arr, effects,
                        covariance, certificate)


def _certificate(path, table) -> dict:
    """The ``[certificate]`` table: header fields, each a string (numbers and dates as written)."""
    if not isinstance(table, dict) or any(isinstance(v, (dict, list)) for v in table.values()):
        raise ValueError(f"{path}: [certificate] must be a table of key = \"text\" fields")
    return {str(k): str(v) for k, v in table.items()}


def covariance_names(names) -> list:
    """The parameter names of the ``[calibration]`` covariance: ``"L1.x" ... "L1.b"`` per sensor."""
    return [f"{nm}.{p}" for nm in names for p in PARAMS_TANGENT]


def _covariance(path, table, names):
    """The ``[calibration]`` table's covariance ``(5n, 5n)``, checked; None when absent."""
    if table is None:
        return None
    if not isinstance(table, dict) or "covariance" not in table:
        raise ValueError(f"{path}: [calibration] needs 'parameters' and 'covariance'")
    want = covariance_names(names)
    if list(table.get("parameters", [])) != want:
        raise ValueError(f"{path}: [calibration] parameters must be {want[0]} ... {want[-1]} (5 per sensor, "
                         f"in the order of the sensors), got {table.get('parameters')!r}")
    try:
        cov = np.asarray(table["covariance"], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: [calibration] covariance must be a {len(want)} x {len(want)} table of numbers") from None
    if cov.shape != (len(want), len(want)) or not np.all(np.isfinite(cov)):
        raise ValueError(f"{path}: [calibration] covariance must be {len(want)} x {len(want)} finite numbers, "
                         f"got shape {cov.shape}")
    if np.max(np.abs(cov - cov.T)) > 1e-9 * max(np.max(np.abs(cov)), 1e-300) or np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) < -1e-9 * np.max(np.abs(cov)):
        raise ValueError(f"{path}: [calibration] covariance is not symmetric positive semi-definite")
    return cov


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
    if layout.covariance is not None:
        lines += ["[calibration]",
                  "# the calibration's covariance of the parameters below: mm (x y z, TCS) and rad (a b: the beam's",
                  "# tilt about the axes e1, e2 of metrology.core.model.direction_basis of the direction above)",
                  "parameters = [" + ", ".join(f'"{p}"' for p in covariance_names(layout.names)) + "]",
                  "covariance = ["]
        lines += ["  [" + ", ".join(f"{v:.9g}" for v in row) + "]," for row in layout.covariance]
        lines += ["]", ""]
    if layout.certificate:
        lines += ["[certificate]", "# the calibration certificate's header fields (metro calibrate --meta)"]
        lines += [f"{_key(k)} = {json.dumps(str(v), ensure_ascii=False)}" for k, v in layout.certificate.items()]
        lines.append("")
    return "\n".join(lines)


def _key(k) -> str:
    """A TOML key: bare when it can be, else quoted."""
    import re

    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k, ensure_ascii=False)


def save_layout(layout: SensorLayout, path, header: str = "") -> None:
    """Write ``layout`` to ``path`` atomically."""
    write_text(path, layout_to_toml(layout, header))

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
(2 numbers: tilt about the chart axes e1, e2) and optional ``[sensors.effects.<term>]`` tables of
the head's effect terms (their schema and checks: :mod:`metrology.core.effects.terms`); files with
these keys are read back unchanged. ``metro calibrate`` also
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
            effects[name] = s["effects"]
    terms = []
    if effects:  # the head's terms (imported only here: a layout without them loads no effect)
        from metrology.core.effects.terms import term_from_table
    for name, table in effects.items():
        terms += [term_from_table(path, name, names.index(name), tuple(names), term, t) for term, t in table.items()]
    covariance, terms = _covariance(path, data.get("calibration"), tuple(names), terms)
    certificate = _certificate(path, data.get("certificate", {}))
    zse_arr = None if any(z is None for z in zse) else np.array(zse)
    dse_arr = None if any(z is None for z in dse) else np.array(dse)
    return SensorLayout(tuple(names), np.array(zero), np.array(direction), np.array(noise), np.array(rng), zse_arr, dse_arr, terms,
                        covariance, certificate)


def _certificate(path, table) -> dict:
    """The ``[certificate]`` table: header fields, each a string (numbers and dates as written)."""
    if not isinstance(table, dict) or any(isinstance(v, (dict, list)) for v in table.values()):
        raise ValueError(f"{path}: [certificate] must be a table of key = \"text\" fields")
    return {str(k): str(v) for k, v in table.items()}


def covariance_names(names, terms=None) -> list:
    """The parameter names of the ``[calibration]`` covariance: ``"L1.x" ... "L1.b"`` per sensor, then
    the head terms' (``scale.L2.k``, ...) when the layout has them."""
    return [f"{nm}.{p}" for nm in names for p in PARAMS_TANGENT] + list(() if terms is None else terms.param_names)


def _covariance(path, table, names, terms):
    """The ``[calibration]`` table's covariance: the sensors' ``(5n, 5n)`` and the terms (a
    :class:`HeadTerms` with their rows of it, or None without terms), checked; None when absent."""
    if table is None:
        if terms:
            t = terms[0]
            raise ValueError(f"{path}: sensor {t.names[t.sensors[0]]} effects.{t.name} has no covariance: the "
                             f"layout needs a [calibration] table with {t.full_param_names[0]} among its parameters "
                             f"(write it with metro diagnose --out or metro calibrate)")
        return None, None
    if not isinstance(table, dict) or "covariance" not in table:
        raise ValueError(f"{path}: [calibration] needs 'parameters' and 'covariance'")
    base = covariance_names(names)
    term_names = [p for c in terms for p in c.full_param_names]
    got = list(table.get("parameters", []))
    if got[:len(base)] != base:
        raise ValueError(f"{path}: [calibration] parameters must be {base[0]} ... {base[-1]} (5 per sensor, "
                         f"in the order of the sensors), got {table.get('parameters')!r}")
    missing = [p for p in term_names if p not in got[len(base):]]
    if missing:
        raise ValueError(f"{path}: [calibration] has no covariance of the term parameter {missing[0]} (a term "
                         f"without its covariance cannot enter U95; write it with metro diagnose --out or "
                         f"metro calibrate)")
    stray = [p for p in got[len(base):] if p not in term_names]
    if stray:
        raise ValueError(f"{path}: [calibration] parameter {stray[0]} is no term of the layout's "
                         f"[sensors.effects] tables")
    want = base + term_names
    try:
        cov = np.asarray(table["covariance"], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: [calibration] covariance must be a {len(got)} x {len(got)} table of numbers") from None
    if cov.shape != (len(got), len(got)) or not np.all(np.isfinite(cov)):
        raise ValueError(f"{path}: [calibration] covariance must be {len(got)} x {len(got)} finite numbers, "
                         f"got shape {cov.shape}")
    if np.max(np.abs(cov - cov.T)) > 1e-9 * max(np.max(np.abs(cov)), 1e-300) or np.min(np.linalg.eigvalsh(0.5 * (cov + cov.T))) < -1e-9 * np.max(np.abs(cov)):
        raise ValueError(f"{path}: [calibration] covariance is not symmetric positive semi-definite")
    order = [got.index(p) for p in want]
    cov = cov[np.ix_(order, order)]
    nb = len(base)
    if not terms:
        return cov, None
    from metrology.core.effects.terms import HeadTerms

    return cov[:nb, :nb], HeadTerms(tuple(terms), cov[nb:, nb:], cov[:nb, nb:])


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
        for comp in () if layout.effects is None else layout.effects.on(name):
            from metrology.core.effects.terms import term_to_table

            lines += term_to_table(comp)
        lines.append("")
    terms = layout.effects
    if terms is not None and layout.covariance is None:
        raise ValueError("a layout with effect terms needs the covariance of its calibration (base and terms)")
    if layout.covariance is not None:
        lines += ["[calibration]",
                  "# the calibration's covariance of the parameters below: mm (x y z, TCS) and rad (a b: the beam's",
                  "# tilt about the axes e1, e2 of metrology.core.model.direction_basis of the direction above)",
                  "parameters = [" + ", ".join(f'"{p}"' for p in covariance_names(layout.names, terms)) + "]",
                  "covariance = ["]
        full = layout.covariance if terms is None else np.block([[layout.covariance, terms.cross],
                                                                  [terms.cross.T, terms.cov]])
        lines += ["  [" + ", ".join(f"{v:.9g}" for v in row) + "]," for row in full]
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

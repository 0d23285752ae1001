"""A head's effect terms as a layout carries them: the properties of its sensors the simple model lacks.

``metro diagnose --out`` and ``metro calibrate`` write them and every consumer of a layout applies
them (:mod:`metrology.core.effects.apply`). Only the effects that are properties of the head
travel in a layout (:data:`HEAD_TERMS`): a sensor's gain (``scale``), its incidence response
(``incidence``), its characteristic (``nonlinearity``) and the temperature coefficient of its zero
(``drift`` with ``variable = "temp"``). Effects of the set-up (``pose_error``, ``plane_form``,
``outliers``) and of one run's time (a knock, ``shift``; a drift in time or through the run's own
thermal lags) are not properties of the head: :func:`why_not_a_head_term` says why.

The layout's schema, one table per term under its sensor (a public contract, README "File formats")::

    [[sensors]]
    name = "L2"
    ...
    [sensors.effects.scale]
    k = 0.0052                  # the term's parameters, in the registry's units
    k_stderr = 0.0003           # and their standard errors
    [sensors.effects.drift]
    variable = "temp"           # the member's options (see OPTIONS)
    ref_c = 20.4
    rate_mm_per_K = 0.0031
    rate_mm_per_K_stderr = 0.0002

and the ``[calibration]`` covariance carries the terms' parameters after the sensors' five each
(names ``<term>.<sensor>[@member].<param>``, e.g. ``scale.L2.k``): the joint covariance of the fit
that estimated them, base and terms together. A term without its rows there is refused.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["HeadTerms", "HEAD_TERMS", "OPTIONS", "TERM_LIMITS", "why_not_a_head_term", "term_from_table",
           "term_to_table", "is_head_term", "refuse_terms"]

#: the registry entries a layout carries: properties of a sensor that hold from calibration to production
HEAD_TERMS = ("scale", "incidence", "nonlinearity", "drift")

#: each head term's options (TOML key -> the component's attribute), besides its parameters
OPTIONS = {
    "scale": {},
    "incidence": {"order": "order"},
    "nonlinearity": {"order": "order", "knots": "knots", "span_mm": "span", "inner_mm": "inner_mm"},
    "drift": {"variable": "variable", "ref_c": "ref"},
}

#: the largest magnitude of each parameter a layout may state (a value beyond is a unit or sign
#: mistake, not a sensor): a gain of 5 % (triangulation sensors are trimmed to a few 0.1 %), 1 mm of
#: incidence bias at 45 deg or of characteristic at the range end (datasheets: tens of um), 0.1 mm/K
#: of zero drift (10x the worst mount seen, 10 um/K)
TERM_LIMITS = {"k": 0.05, "c_mm": 1.0, "c2_mm": 1.0, "c3_mm": 1.0, "c4_mm": 1.0, "c5_mm": 1.0,
               "rate_mm_per_K": 0.1}
#: spline coefficients of a nonlinearity (``s1_mm`` ...): as the Legendre ones
SPLINE_LIMIT_MM = 1.0

#: why an effect the diagnosis may name does not go into a head's layout
NOT_HEAD = {
    "pose_error": "an error of the tracker's poses in this run (the set-up), not of the head",
    "plane_form": "the datum's form (the set-up): fit the datum's form or flatten it, not the head",
    "datum_tilt": "the datum's tilt (the set-up), not the head",
    "outliers": "gross readings of this run: drop or repeat them",
    "shift": "a knock: recalibrate after fixing the mount",
    "drift@time": "a drift in time during this run (a warm-up): let the head settle and recalibrate",
    "drift@lag": "the zero following this run's temperature history with a lag: not a coefficient the "
                 "production log's temperature alone can apply; let the head settle",
}


def is_head_term(comp) -> bool:
    """Whether the component ``comp`` (a registry entry, fitted) is a property of the head a layout carries."""
    if comp.name not in HEAD_TERMS or not comp.sensors or len(comp.sensors) != 1:
        return False
    if comp.name == "drift":
        return comp.variable == "temp" and comp.order == 1
    return True


def why_not_a_head_term(comp) -> str:
    """Why ``comp`` does not go into a head's layout (empty when it does)."""
    if is_head_term(comp):
        return ""
    if comp.name == "drift":
        return NOT_HEAD["drift@lag" if comp.variable == "lag" else "drift@time"]
    return NOT_HEAD.get(comp.name, f"{comp.name} is not a property of one sensor of the head")


@dataclass(frozen=True)
class HeadTerms:
    """The terms of a layout, fitted, with their covariance.

    Attributes
    ----------
    components : tuple of Component, each on one sensor, with ``values``, ``stderr`` and the
        layout's sensor ``names``
    cov : (k, k) float, the terms' covariance (their parameters in ``param_names`` order, registry units)
    cross : (5n, k) float, the covariance of the sensors' chart parameters ``(x, y, z, a, b)`` (mm,
        rad; the layout's ``[calibration]`` order) with the terms' parameters
    """

    components: tuple
    cov: np.ndarray
    cross: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "components", tuple(self.components))
        k = self.n_params
        cov = np.asarray(self.cov, float).reshape(k, k)
        object.__setattr__(self, "cov", 0.5 * (cov + cov.T))
        object.__setattr__(self, "cross", np.asarray(self.cross, float).reshape(-1, k))

    @property
    def n_params(self) -> int:
        return sum(c.n_params for c in self.components)

    @property
    def param_names(self) -> tuple:
        return tuple(p for c in self.components for p in c.full_param_names)

    def on(self, sensor: str) -> tuple:
        """The components acting on the sensor named ``sensor``."""
        return tuple(c for c in self.components if c.names[c.sensors[0]] == sensor)

    def subset(self, names, old_names) -> "HeadTerms | None":
        """The terms on the sensors ``names`` of a layout whose sensors were ``old_names`` (their
        indices renumbered), or None when none acts on them."""
        keep, cols, off = [], [], 0
        for c in self.components:
            nm = old_names[c.sensors[0]]
            if nm in names:
                keep.append(replace(c, sensors=(list(names).index(nm),), names=tuple(names)))
                cols += range(off, off + c.n_params)
            off += c.n_params
        if not keep:
            return None
        rows = [5 * old_names.index(nm) + j for nm in names for j in range(5)]
        return HeadTerms(tuple(keep), self.cov[np.ix_(cols, cols)], self.cross[np.ix_(rows, cols)])

    def needs(self) -> tuple:
        """The covariates the terms need besides the readings: ``"temperature_c"``, ``"incidence"``."""
        out = []
        if any(c.name == "drift" for c in self.components):
            out.append("temperature_c")
        if any(c.name == "incidence" for c in self.components):
            out.append("incidence")
        return tuple(out)

    def describe(self) -> list:
        """Each term as plain data: label, sensor, parameters with value, stderr and U (k = 2)."""
        out = []
        for c in self.components:
            d = c.describe()
            for v in d["params"].values():
                v["U_k2"] = None if v["stderr"] is None else 2.0 * v["stderr"]
            out.append(d)
        return out


def _known(sensor: str) -> str:
    return (f"sensor {sensor}: known terms are {', '.join(HEAD_TERMS)} (the head's properties; "
            f"set-up and time-local effects are not written to a layout)")


def term_from_table(path, sensor: str, index: int, names: tuple, term: str, table) -> object:
    """The component of the ``[sensors.effects.<term>]`` table of sensor ``sensor`` (index ``index`` of
    ``names``), checked: its name, options, parameters and their standard errors, each within its
    physical range. Raises ValueError with one line naming the file, the sensor and the key."""
    from metrology.core.effects import REGISTRY

    where = f"{path}: sensor {sensor} effects.{term}"
    if term not in HEAD_TERMS:
        raise ValueError(f"{path}: unknown effect term {term!r} on {_known(sensor)}")
    if not isinstance(table, dict):
        raise ValueError(f"{where} must be a table of its parameters (e.g. k = 0.005, k_stderr = 0.0003), "
                         f"got {table!r}")
    kw = {}
    for key, attr in OPTIONS[term].items():
        if key in table:
            v = table[key]
            kw[attr] = tuple(float(x) for x in v) if isinstance(v, list) else v
    if term == "drift":
        if kw.get("variable", "temp") != "temp":
            raise ValueError(f"{where}: variable {kw['variable']!r}: a layout carries a temperature coefficient "
                             f"(variable = \"temp\") only; {NOT_HEAD['drift@time']}")
        if "ref" not in kw:
            raise ValueError(f"{where} needs ref_c, the reference temperature (deg C) of its zero")
    if term == "nonlinearity":
        kw["with_gain"] = "k" in table
    try:
        comp = REGISTRY[term]((index,), names=tuple(names), **kw)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    allowed = set(OPTIONS[term]) | set(comp.param_names) | {p + "_stderr" for p in comp.param_names}
    extra = sorted(set(table) - allowed)
    if extra:
        raise ValueError(f"{where}: unknown key(s) {', '.join(extra)}; expected {', '.join(sorted(allowed))}")
    vals, se = [], []
    for p in comp.param_names:
        for key, out in ((p, vals), (p + "_stderr", se)):
            if key not in table:
                raise ValueError(f"{where} lacks {key}" + (" (a term without its standard error and covariance "
                                                          "cannot enter U95)" if key.endswith("_stderr") else ""))
            v = table[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"{where}.{key} must be a finite number, got {v!r}")
            out.append(float(v))
        lim = TERM_LIMITS.get(p, SPLINE_LIMIT_MM if p.startswith("s") and p.endswith("_mm") else None)
        if lim is not None and abs(vals[-1]) > lim:
            raise ValueError(f"{where}.{p} = {vals[-1]:g} outside its physical range |{p}| <= {lim:g} "
                             f"({comp.param_units[comp.param_names.index(p)]}): a unit or sign mistake?")
        if se[-1] < 0:
            raise ValueError(f"{where}.{p}_stderr = {se[-1]:g} must be >= 0")
    return comp.with_values(vals, se)


def term_to_table(comp) -> list:
    """The TOML lines of one component's ``[sensors.effects.<name>]`` table (header included)."""
    import json

    lines = [f"[sensors.effects.{comp.name}]"]
    for key, attr in OPTIONS[comp.name].items():
        v = getattr(comp, attr)
        default = {"order": 3 if comp.name == "nonlinearity" else 2, "knots": 4}.get(key)
        if v is None or (key in ("order", "knots") and v == default):
            continue
        if key == "knots" and getattr(comp, "order", 3) != 0:
            continue
        if isinstance(v, tuple):
            lines.append(f"{key} = [" + ", ".join(f"{float(x):.9g}" for x in v) + "]")
        elif isinstance(v, str):
            lines.append(f"{key} = {json.dumps(v)}")
        elif isinstance(v, float):
            lines.append(f"{key} = {v:.9g}")
        else:
            lines.append(f"{key} = {v}")
    se = comp.stderr if comp.stderr is not None else np.full(comp.n_params, np.nan)
    for p, v, s in zip(comp.param_names, comp.values, se):
        lines += [f"{p} = {float(v):.9g}", f"{p}_stderr = {float(s):.9g}"]
    return lines


def refuse_terms(layout, source, command: str, why: str) -> None:
    """Refuse (ValueError, one line) a layout with head terms in a command that cannot apply them:
    never measured silently with the simple model."""
    if layout is None or layout.effects is None:
        return
    labels = ", ".join(c.label for c in layout.effects.components)
    raise ValueError(f"{source}: the layout has effect terms ({labels}) that metro {command} cannot apply ({why}); "
                     f"use a layout without [sensors.effects], or metro simulate-log and metro measure, which apply them")

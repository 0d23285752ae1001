"""The open search's vocabulary: the variables an export carries, and the terms made of them.

Where the catalogue does not explain the residuals, :mod:`metrology.diagnosis.search` looks for
their dependence on the variables of the run, per sensor. The variables are read from the export
and the base calibration, not from any list of effects; each has a name (``variables`` in the
``--json`` output):

=====================  ======================================================================
``d``                  the sensor's reading (mm; the base model's, ``d0``, free of noise)
``delta_d``            its change since the previous pose in time order (mm)
``sign_delta_d``       the sign of that change (the direction the stand-off last moved)
``incidence``          ``tan^2`` of the beam's incidence angle on the datum
``time``               hours since the first pose (the pose index where the export has none)
``pose_index``         the pose's row in the export
``temperature``        deg C about the run's mean (where the export has it)
``temperature_rate``   its rate of change, K/h
``spot``               the spot's position on the datum plate (mm, the plate's axes)
``d_other``            another sensor's reading (mm; ``d_other:L1`` names which)
``attitude``           the head's orientation: the nine entries of each pose's rotation
``tails``              the residuals' distribution (tested apart: a contaminated normal)
=====================  ======================================================================

The terms (:func:`terms_for`), each a few columns whose coefficients are fitted with the sensor's
base parameters: every variable alone (a straight line in it, except ``d``, ``time`` and
``incidence``, which the catalogue's own families cover); periodic terms ``sin, cos(2 pi x / P)``
of ``d``, ``time`` and ``pose_index`` over a frequency scan (from one period over the span to the
Nyquist period of the sampling, in steps of a quarter of the span's fundamental); a smooth field
over the plate (a quadratic, and plane waves of 30-300 mm in 12 directions); the other sensors'
readings (linearly, squared, and times the sensor's own); the attitude; and the products of two of
``d``, ``incidence``, ``time``, ``temperature`` and ``delta_d``. A column that is constant, or all
but constant, over the poses is dropped (a constant is the zero point's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["VARIABLES", "Term", "terms_for", "variables_for", "FIELD_MAX_ORDER", "FIELD_OVERSAMPLING",
           "FIELD_MAX_WAVES", "FREQUENCY_OVERSAMPLING", "wave_vectors"]

#: the vocabulary (see the module); the search names its terms' variables from these only
VARIABLES = ("d", "delta_d", "sign_delta_d", "incidence", "time", "pose_index", "temperature", "temperature_rate",
             "spot", "d_other", "attitude", "tails")
#: the plate's polynomial fields: orders 2 to this (order 4: 14 columns, a field of a few bumps)
FIELD_MAX_ORDER = 4
#: the plate's 2-D frequency scan: its grid step is the span's fundamental over this, per axis
FIELD_OVERSAMPLING = 2
#: at most this many plane waves are scanned (the grid coarsened to fit: the search's multiplicity)
FIELD_MAX_WAVES = 1000
#: the frequency scan's step is the span's fundamental over this
FREQUENCY_OVERSAMPLING = 4


@dataclass(frozen=True)
class Term:
    """One candidate term on one sensor.

    key : str, unique on the sensor (``periodic(d, P=6.31 mm)``); variables : tuple of str, from
    :data:`VARIABLES`; columns : (p, k) float, zero at blank readings; kind : ``"line"`` (one
    column: the term is ``c x``), ``"periodic"`` (``sin``, ``cos``: an amplitude and a phase) or
    ``"shape"`` (several columns: reported by its peak-to-valley); expr : str, the variable as the
    equation writes it, with its unit (``sign(delta_d)``, ``(T - 21.3 C) [K]``); unit : str, the unit
    of ``x`` (``"1"``, ``"K"``, ...); period : float or None, in ``period_unit``.
    """

    key: str
    variables: tuple
    columns: np.ndarray
    kind: str
    expr: str
    unit: str = "1"
    period: float | None = None
    period_unit: str = ""


def variables_for(export, cov, d0, i):
    """The variables of sensor ``i`` (a dict name -> (p,) float array), from the export (its
    time, temperature and poses), the covariates ``cov`` and the base readings ``d0 (p, n)`` mm."""
    p = d0.shape[0]
    t = np.asarray(cov.time_h, float)
    order = np.argsort(t, kind="stable")
    di = np.asarray(d0[:, i], float)
    delta = np.zeros(p)
    delta[order[1:]] = np.diff(di[order])
    out = {"d": di, "delta_d": delta, "sign_delta_d": np.sign(delta), "time": t,
           "pose_index": np.arange(p, dtype=float),
           "incidence": np.clip(1.0 / np.maximum(cov.cos_inc[:, i], 1e-6) ** 2 - 1.0, 0.0, None)}
    T = np.asarray(cov.temp_c, float)
    if np.all(np.isfinite(T)) and np.ptp(T) > 0:
        out["temperature"] = T - float(np.mean(T))
        rate = np.zeros(p)
        rate[order] = np.gradient(T[order], t[order]) if np.all(np.diff(t[order]) > 0) else 0.0
        out["temperature_rate"] = rate
    return out


def _ok(col, fin) -> bool:
    c = col[fin]
    return len(c) > 2 and float(np.ptp(c)) > 1e-9 * max(float(np.max(np.abs(c))), 1e-300)


def _periods(x, fin):
    """The frequency scan of ``x``: periods from its span down to twice its median step."""
    xs = np.sort(x[fin])
    span = float(xs[-1] - xs[0])
    steps = np.diff(xs)
    step = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    if span <= 0 or step <= 0:
        return []
    f_lo, f_hi = 1.0 / span, 1.0 / (2.0 * step)
    freqs = np.arange(f_lo, f_hi, f_lo / FREQUENCY_OVERSAMPLING)
    return [1.0 / f for f in freqs]


def wave_vectors(xy) -> list:
    """The 2-D frequency scan's wave vectors (1/mm) for spots ``xy (m, 2)`` mm: a grid of step
    ``1 / (FIELD_OVERSAMPLING x span)`` per axis over the half plane, ``|k|`` from one wave over the
    larger span to the spots' median nearest-neighbour spacing (scattered spots, not a grid; coarsened
    until at most ``FIELD_MAX_WAVES`` remain)."""
    if len(xy) < 4:
        return []
    span = np.ptp(xy, axis=0)
    if np.any(span <= 0):
        return []
    dd = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(dd, np.inf)
    nn = np.min(dd, axis=1)
    h = float(np.median(nn[np.isfinite(nn) & (nn > 0)])) if np.any(nn > 0) else 0.0
    if h <= 0:
        return []
    k_lo, k_hi = 1.0 / float(np.max(span)), 1.0 / h  # scattered spots alias little: down to their spacing
    over = float(FIELD_OVERSAMPLING)
    while True:
        step = 1.0 / (over * span)
        kx = np.arange(0.0, k_hi + 1e-12, step[0])
        ky = np.arange(-np.floor(k_hi / step[1]), np.floor(k_hi / step[1]) + 1) * step[1]
        KX, KY = np.meshgrid(kx, ky, indexing="ij")
        k = np.hypot(KX, KY)
        keep = (k >= k_lo) & (k <= k_hi) & ((KX > 0) | (KY > 0))
        if keep.sum() <= FIELD_MAX_WAVES or over <= 0.5:
            return list(zip(KX[keep].tolist(), KY[keep].tolist()))
        over /= 1.25


def terms_for(export, cov, d0, i, names, fin) -> list:
    """The candidate terms of sensor ``i`` (see the module); ``fin (p,)`` its finite readings."""
    v = variables_for(export, cov, d0, i)
    out = []

    def add(key, variables, cols, kind, expr, unit="1", period=None, period_unit=""):
        cols = np.atleast_2d(np.asarray(cols, float).T).T
        keep = [k for k in range(cols.shape[1]) if _ok(cols[:, k], fin)]
        if keep and (kind != "periodic" or len(keep) == 2):
            out.append(Term(key, tuple(variables), np.where(fin[:, None], cols[:, keep], 0.0), kind, expr, unit,
                            period, period_unit))

    add("delta_d", ("delta_d",), v["delta_d"], "line", "delta_d [mm]", "mm")
    add("sign_delta_d", ("sign_delta_d",), v["sign_delta_d"], "line", "sign(delta_d)")
    add("pose_index", ("pose_index",), v["pose_index"], "line", "pose index")
    if "temperature" in v:
        add("temperature^2", ("temperature",), v["temperature"] ** 2, "line", "(T - mean)^2 [K^2]", "K^2")
        add("temperature_rate", ("temperature_rate",), v["temperature_rate"], "line", "dT/dt [K/h]", "K/h")
    units = {"d": "mm", "time": "h", "pose_index": ""}
    for name in ("d", "time", "pose_index"):
        x = v[name]
        for P in _periods(x, fin):
            w = 2 * np.pi * x / P
            add(f"periodic({name}, P={P:.4g}{' ' + units[name] if units[name] else ''})", (name,),
                np.column_stack([np.sin(w), np.cos(w)]), "periodic", name, units[name], P, units[name])
    s, t_ = cov.spot_st[:, i, 0], cov.spot_st[:, i, 1]
    sc = max(float(np.max(np.abs(np.column_stack([s, t_])[fin]))) if fin.any() else 1.0, 1e-9)
    u, w_ = s / sc, t_ / sc  # unitless: the columns' sizes alike
    for order in range(2, FIELD_MAX_ORDER + 1):
        cols = [u**a * w_**(m - a) for m in range(1, order + 1) for a in range(m + 1)]
        add(f"spot field(order {order})", ("spot",), np.column_stack(cols), "shape",
            f"a polynomial field of order {order} over the plate")
    for kx, ky in wave_vectors(np.column_stack([s, t_])[fin]):
        w = 2 * np.pi * (kx * s + ky * t_)
        lam, ang = 1.0 / float(np.hypot(kx, ky)), float(np.degrees(np.arctan2(ky, kx)))
        add(f"spot wave({lam:.4g} mm, {ang:.0f} deg)", ("spot",), np.column_stack([np.sin(w), np.cos(w)]),
            "shape", f"a plane wave of {lam:.4g} mm at {ang:.0f} deg over the plate")
    di = v["d"]
    for j in range(d0.shape[1]):
        if j == i:
            continue
        dj = np.asarray(d0[:, j], float)
        xj = dj - float(np.nanmean(dj))
        add(f"d_other:{names[j]}", ("d_other",), xj, "line", f"(d_{names[j]} - mean) [mm]", "mm")
        add(f"d_other:{names[j]}^2", ("d_other",), xj**2, "line", f"(d_{names[j]} - mean)^2 [mm^2]", "mm^2")
        add(f"d_other:{names[j]} x d", ("d_other", "d"), xj * (di - float(np.mean(di))), "line",
            f"(d_{names[j]} - mean)(d - mean) [mm^2]", "mm^2")
    R = np.asarray(export.tcs2tracker_rot, float).reshape(len(di), 9)
    add("attitude", ("attitude",), R, "shape", "a linear function of the head's attitude")
    prod = {"d": (v["d"] - float(np.mean(v["d"])), "(d - mean) [mm]", "mm"),
            "incidence": (v["incidence"], "tan^2(incidence)", "1"),
            "time": (v["time"] - float(np.mean(v["time"])), "(t - mean) [h]", "h"),
            "delta_d": (v["delta_d"], "delta_d [mm]", "mm")}
    if "temperature" in v:
        prod["temperature"] = (v["temperature"], "(T - mean) [K]", "K")
    keys = list(prod)
    for a in range(len(keys)):
        for b in range(a + 1, len(keys)):
            (xa, ea, ua), (xb, eb, ub) = prod[keys[a]], prod[keys[b]]
            add(f"{keys[a]} x {keys[b]}", (keys[a], keys[b]), xa * xb, "line", f"{ea} x {eb}",
                "*".join(u for u in (ua, ub) if u != "1") or "1")
    return out

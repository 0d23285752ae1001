"""One place that applies a layout's head terms to raw readings.

A sensor with terms reads ``d = d0 + f(d0; theta, covariates)`` (mm) where ``d0`` is what the
simple model of :mod:`metrology.core.model` predicts (the distance along its beam from its zero
point) and ``f`` the sum of its terms (:mod:`metrology.core.effects`). Every consumer of a
layout (measure, normals, the controller's ``surface_normal``, the drift watch, diagnose given an
extended layout) hands the simple model ``d0``: :func:`correct_readings` inverts ``d = d0 + f(d0)``
by fixed-point iteration (the terms change by ``f' ~ 1e-2`` per mm of reading: each step gains two
orders) and returns the sensitivity of ``d0`` to the terms' parameters,

    dd0/dtheta = -(df/dtheta) / (1 + df/dd0),

through which the terms' covariance (and its correlation with the base parameters) enters U95.

The covariates: a temperature coefficient needs the temperature (deg C) of each reading; an
incidence response needs the cosine of each beam's incidence angle on the surface (from the
datum plane in a calibration, from the hole's own normal in production:
:func:`incidence_from_normal`). A term whose covariate is missing raises ValueError naming it; no
term is skipped.

:func:`remove_terms` is the one place that removes a layout's terms from a production reading's
row, for every consumer that reads the head at a surface (``metro measure`` through
:func:`metrology.measure.effects.apply_terms`, the controller's ``surface_normal``, ``metro normals``
through :func:`metrology.panel.head_terms.corrected`): the temperature the caller gives, each beam's
incidence from the row's own micro-plane of the raw readings (:func:`micro_normals`, any 3 finite
readings). **A covariate not known on a row** (a blank temperature; fewer than 3 finite readings, so
no plane and no incidence) blanks that row's readings of the sensors whose terms need it
(:data:`UNKNOWN_COVARIATE`): no reading goes on that the model cannot place, and the row is measured
on its other readings or not at all. A term that needs no covariate (a gain, a nonlinearity) is
removed on every row; the readings of sensors without terms pass unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects.base import Covariates

__all__ = ["Corrected", "correct_readings", "covariates_for", "incidence_from_normal", "micro_normals", "remove_terms",
           "spot_incidence",
           "INVERSION_STEPS", "INCIDENCE_PASSES", "UNKNOWN_COVARIATE"]

#: fixed-point steps of the inversion: a 1 % gain leaves 1e-8 of its term after 4
INVERSION_STEPS = 4
#: passes of the incidence in :func:`remove_terms`: the normal of the raw readings, the incidence, the corrected
#: readings. A 50 um bias moves the normal by about 1 mrad over the spots' 50 mm, which moves ``tan^2`` of a 30 deg
#: incidence by 1.5e-3 of itself: 0.1 um of a 50 um term, so a second pass changes nothing
INCIDENCE_PASSES = 1
#: what :func:`remove_terms` does with a reading whose term's covariate the row does not give (a blank
#: temperature; an incidence where fewer than 3 readings make no plane): the reading is blanked (NaN), never
#: corrected at a guessed covariate (normal incidence, a reference temperature)
UNKNOWN_COVARIATE = "blank"


@dataclass(frozen=True)
class Corrected:
    """Readings with the head's terms removed.

    Attributes
    ----------
    d : (N, n) float, mm, what the simple model predicts (NaN where the raw reading is)
    jac : (N, n, k) float, mm per unit parameter: ``dd0/dtheta`` of the terms' parameters (in
        :attr:`HeadTerms.param_names` order)
    term : (N, n) float, mm, the terms removed (``raw - d``)
    """

    d: np.ndarray
    jac: np.ndarray
    term: np.ndarray


def covariates_for(layout, n_rows, temp_c=None, cos_inc=None) -> Covariates:
    """The covariates of ``n_rows`` readings of ``layout``'s sensors for its terms: ``temp_c (N,)``
    deg C, ``cos_inc (N, n)`` (|cos| of each beam's incidence angle); missing ones are NaN (a term
    that needs them raises in :func:`correct_readings`)."""
    n = layout.n
    t = np.full(n_rows, np.nan) if temp_c is None else np.asarray(temp_c, float).reshape(n_rows)
    c = np.full((n_rows, n), np.nan) if cos_inc is None else np.asarray(cos_inc, float).reshape(n_rows, n)
    return Covariates(np.zeros(n_rows), t, c, np.full((n_rows, n), np.nan), np.zeros((n_rows, n, 2)),
                      np.asarray(layout.range_mm, float))


def _check(terms, cov, names, what):
    for c in terms.components:
        if c.name == "drift" and not np.all(np.isfinite(cov.temp_c)):
            raise ValueError(f"{what}: the layout's term {c.label} (a temperature coefficient of the zero) needs "
                             f"the temperature of every reading: the column temperature_c (deg C) is missing or blank")
        if c.name == "incidence" and not np.all(np.isfinite(cov.cos_inc[:, c.sensors[0]])):
            raise ValueError(f"{what}: the layout's term {c.label} (an incidence response) needs each beam's "
                             f"incidence angle, which these readings do not give")
        if c.name == "nonlinearity" and not np.all(np.isfinite(cov.range_mm[c.sensors[0]])):
            raise ValueError(f"{what}: the layout's term {c.label} needs the range_mm of sensor "
                             f"{names[c.sensors[0]]} (its characteristic is over that range)")


def correct_readings(terms, d, cov: Covariates, what="readings") -> Corrected:
    """The readings ``d (N, n)`` mm with ``terms`` (:class:`~metrology.core.effects.terms.HeadTerms`)
    removed, and their sensitivity to the terms' parameters (:class:`Corrected`).

    ``cov`` the covariates of these readings (:func:`covariates_for`); ``what`` names them in an
    error (a term whose covariate is missing raises ValueError)."""
    d = np.asarray(d, float)
    N, n = d.shape
    k = 0 if terms is None else terms.n_params
    if terms is None or not terms.components:
        return Corrected(d, np.zeros((N, n, 0)), np.zeros((N, n)))
    names = terms.components[0].names
    _check(terms, cov, names, what)
    fin = np.isfinite(d)
    dz = np.where(fin, d, 0.0)
    cols = np.zeros(n, bool)
    for c in terms.components:
        cols[c.sensors[0]] = True
    d0 = dz.copy()
    live = [c for c in terms.components if c.uses_d0]
    with np.errstate(invalid="ignore"):
        fixed = np.zeros((N, n))  # the terms that do not depend on the reading: evaluated once
        for c in terms.components:
            if not c.uses_d0:
                fixed += c.evaluate(c.values, d0, cov)
        for _ in range(INVERSION_STEPS if live else 1):
            f = fixed.copy()
            for c in live:
                f += c.evaluate(c.values, d0, cov)
            d0 = np.where(cols[None, :], dz - f, dz)
        slope = np.ones((N, n))
        J = np.zeros((N, n, k))
        off = 0
        for c in terms.components:
            slope += c.d_dd0(c.values, d0, cov)
            J[..., off:off + c.n_params] = c.jacobian(c.values, d0, cov)
            off += c.n_params
        J = -J / slope[..., None]
    d0 = np.where(fin, d0, np.nan)
    J = np.where(fin[..., None], J, 0.0)
    return Corrected(d0, J, np.where(fin, d - d0, 0.0))


def incidence_from_normal(layout, normal) -> np.ndarray:
    """``(N, n)``: |cos| of each beam's incidence angle on a surface of unit normal ``normal (N, 3)``
    TCS (the hole's micro-plane; NaN where the normal is)."""
    return np.abs(np.asarray(normal, float) @ np.asarray(layout.direction, float).T)


def micro_normals(layout, d) -> np.ndarray:
    """``(N, 3)`` unit, TCS: the least-squares plane ``z = c + g_x x + g_y y`` through the finite
    projection points of each row of ``d (N, n)`` mm (NaN with fewer than 3), along the beams."""
    w = np.isfinite(d).T.astype(float)  # (n, N), sensor-major
    dT = np.where(w > 0, d.T, 0.0)
    E, u = layout.zero, layout.direction
    x, y, z = (E[:, k, None] + dT * u[:, k, None] for k in range(3))
    cnt = np.maximum(w.sum(0), 1.0)
    xc, yc, zc = (v - (w * v).sum(0) / cnt for v in (x, y, z))
    sxx, syy, sxy = (w * xc * xc).sum(0), (w * yc * yc).sum(0), (w * xc * yc).sum(0)
    sxz, syz = (w * xc * zc).sum(0), (w * yc * zc).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        det = sxx * syy - sxy * sxy
        gx, gy = (syy * sxz - sxy * syz) / det, (sxx * syz - sxy * sxz) / det
        s = 1.0 if np.mean(u[:, 2]) > 0 else -1.0
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=1) * (s / np.sqrt(1.0 + gx * gx + gy * gy))[:, None]
    n[w.sum(0) < 3] = np.nan
    return n


def spot_incidence(layout, d, normal, shape) -> np.ndarray:
    """``(N, n)``: |cos| of each beam's incidence on the surface at its own spot, the surface the plane of
    unit normal ``normal (N, 3)`` (TCS, either sign; :func:`micro_normals`) through the row's spots, bent by
    ``shape (N, 3, 3)`` 1/mm TCS (the local surface's shape operator square to the axis, positive where it
    bends away from the head: :func:`metrology.measure.surface.fit_surface`'s ``K``). At the spot ``S_i``
    (``q = S_i - c e_z``, ``c`` where the plane meets the axis) the surface's normal toward the head is
    ``m + K q_t`` to first order (``q_t`` the part of ``q`` square to ``m``): on R 500 a spot 50 mm off the
    axis sees the surface turned by 0.1 rad, which changes a 30 deg incidence's ``1 - cos`` by a third."""
    E, u = layout.zero, layout.direction
    s = 1.0 if np.mean(u[:, 2]) > 0 else -1.0
    normal = np.asarray(normal, float)
    m = -normal * np.sign(normal[:, 2:3] * s)  # toward the head (against the beams)
    S = E[None] + np.asarray(d, float)[..., None] * u[None]  # (N, n, 3)
    fin = np.isfinite(S[..., 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        cnt = np.maximum(fin.sum(1), 1)
        bar = np.where(fin[..., None], S, 0.0).sum(1) / cnt[:, None]  # (N, 3)
        c = bar[:, 2] + (m[:, 0] * bar[:, 0] + m[:, 1] * bar[:, 1]) / m[:, 2]  # the plane through bar meets the axis
        q = S - c[:, None, None] * np.array([0.0, 0.0, 1.0])
        qt = q - np.einsum("hni,hi->hn", q, m)[..., None] * m[:, None, :]
        nn = m[:, None, :] + np.einsum("hij,hnj->hni", np.asarray(shape, float), qt)
        return np.abs(np.einsum("hni,ni->hn", nn, u)) / np.linalg.norm(nn, axis=2)


def remove_terms(layout, d, temp_c=None, what="readings", shape=None) -> Corrected:
    """The readings ``d (N, n)`` mm of ``layout``'s sensors, one row a pose of the head at a surface, with
    the layout's terms removed (module docstring): ``temp_c (N,)`` deg C, each row's temperature (None: a
    temperature coefficient raises ValueError naming ``what``'s column); each beam's incidence from the row's
    micro-plane, or at its spot on the local surface where ``shape (N, 3, 3)`` 1/mm TCS gives it (the panel
    known: :func:`spot_incidence`). Where a row's covariate is not known, the readings of the sensors whose
    terms need it are blanked (:data:`UNKNOWN_COVARIATE`). ``layout`` without terms: ``d`` itself."""
    d = np.asarray(d, float)
    terms = layout.effects
    if terms is None or not terms.components:
        return Corrected(d, np.zeros(d.shape + (0,)), np.zeros(d.shape))
    needs = terms.needs()
    cos = None
    passes = INCIDENCE_PASSES if "incidence" in needs else 0
    incidence = (lambda dd: incidence_from_normal(layout, micro_normals(layout, dd))) if shape is None else (
        lambda dd: spot_incidence(layout, dd, micro_normals(layout, dd), shape))
    if passes:
        cos = incidence(d)
    temp = None if temp_c is None else np.where(np.isfinite(temp_c), temp_c, np.nan)
    for k in range(max(passes, 1)):
        corr = _correct_rows(terms, d, covariates_for(layout, len(d), temp, cos), what)
        if k + 1 < passes:
            cos = incidence(corr.d)
    return corr


def _correct_rows(terms, d, cov, what):
    """:func:`correct_readings` where the covariates are known; elsewhere the readings of the sensors whose own
    terms need the unknown covariate blanked (a gain on another sensor is still removed)."""
    from dataclasses import replace

    ok = np.ones(d.shape, bool)
    ok_t = np.isfinite(cov.temp_c)
    for c in terms.components:
        i = c.sensors[0]
        if c.name == "drift":
            ok[:, i] &= ok_t
        elif c.name == "incidence":
            ok[:, i] &= np.isfinite(cov.cos_inc[:, i])
    if ok.all():
        return correct_readings(terms, d, cov, what)
    if "temperature_c" in terms.needs() and not ok_t.any():
        correct_readings(terms, d, cov, what)  # raises, naming the column
    safe = replace(cov, temp_c=np.where(ok_t, cov.temp_c, 20.0),
                   cos_inc=np.where(np.isfinite(cov.cos_inc), cov.cos_inc, 1.0))
    return correct_readings(terms, np.where(ok, d, np.nan), safe, what)  # the blanked readings stay NaN

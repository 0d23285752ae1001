"""One place that applies a layout's head terms to raw readings.

A sensor with terms reads ``d = d0 + f(d0; theta, covariates)`` (mm) where ``d0`` is what the
simple model of :mod:`metrology.core.model` predicts (the distance along its beam from its zero
point) and ``f`` the sum of its terms (:mod:`metrology.core.effects.sensor`). Every consumer of a
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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.effects.base import Covariates

__all__ = ["Corrected", "correct_readings", "covariates_for", "incidence_from_normal", "INVERSION_STEPS"]

#: fixed-point steps of the inversion: a 1 % gain leaves 1e-8 of its term after 4
INVERSION_STEPS = 4


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

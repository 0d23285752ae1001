"""Casting the sensor beams at the datum height field.

A sensor has a zero point ``P0`` (mm, TCS) and a unit beam direction ``u`` (TCS). With the TCS
pose ``tcs2tracker`` (rotation ``R``, translation ``T`` mm, tracker frame) the point at distance
``d`` mm along the beam is, in the tracker frame,

    p(d) = T + R (P0 + d u) = a + d b,     a = T + R P0,   b = R u.

The true distance is the root of the signed height residual
``f(d) = w(p(d)) - h(s(p(d)), t(p(d)))`` (mm; see :mod:`.surface`), whose derivative is
``f'(d) = n.b - h_s e_s.b - h_t e_t.b``. It is found by Newton's method from the reference-plane
intersection, to ``|step| <= 1e-9 mm``; a beam that does not converge falls back to a sign-change
scan over ``[0, d_max]`` and Brent's method (``xtol`` 1e-12 mm). A beam that meets no surface, or
meets it outside the datum's extent or behind the sensor, is NaN (``valid`` False).

The incidence angle (rad) is the angle between the beam and the local surface normal,
``atan2(|n_local x b|, |n_local . b|)`` in [0, pi/2].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.sim.forward.surface import DatumSurface

__all__ = ["BeamHits", "cast_beams", "CAST_TOL_MM", "MAX_NEWTON"]

#: Newton stops when the step is below this, mm
CAST_TOL_MM = 1e-9
MAX_NEWTON = 60


@dataclass(frozen=True)
class BeamHits:
    """Where every beam meets the datum.

    Attributes
    ----------
    d : (p, n) float, mm, true distance from the zero point; NaN where ``valid`` is False
    incidence : (p, n) float, rad, angle between beam and local surface normal; NaN where invalid
    spot : (p, n, 3) float, mm, tracker frame; NaN where invalid
    valid : (p, n) bool
    """

    d: np.ndarray
    incidence: np.ndarray
    spot: np.ndarray
    valid: np.ndarray


def _residual(surface, a, b, d):
    p = a + d[..., None] * b
    s, t, w = surface.plane_coords(p)
    hs, ht = surface.gradient(s, t)
    f = w - surface.height(s, t)
    df = b @ surface.normal - hs * (b @ surface.axis_s) - ht * (b @ surface.axis_t)
    return f, df


def _bracket(surface, a, b, d_max, n_scan=400):
    """Root by scan + Brent for one beam ``a (3,), b (3,)``; NaN when no sign change."""
    from scipy.optimize import brentq

    grid = np.linspace(0.0, d_max, n_scan)
    f = _residual(surface, np.broadcast_to(a, (n_scan, 3)), np.broadcast_to(b, (n_scan, 3)), grid)[0]
    change = np.nonzero(np.sign(f[:-1]) * np.sign(f[1:]) <= 0)[0]
    if not change.size:
        return np.nan
    k = change[0]
    g = lambda x: float(_residual(surface, a, b, np.asarray(x))[0])  # noqa: E731
    return brentq(g, grid[k], grid[k + 1], xtol=1e-12, rtol=4 * np.finfo(float).eps)


def cast_beams(surface: DatumSurface, zero, direction, tcs2tracker_rot, tcs2tracker_trans,
               d_max: float = 500.0, max_newton: int = MAX_NEWTON) -> BeamHits:
    """True distances and incidence angles of every beam at every pose.

    Parameters
    ----------
    surface : DatumSurface
    zero : (n, 3) float, mm, TCS
    direction : (n, 3) float, TCS (normalised here)
    tcs2tracker_rot : (p, 3, 3) float
    tcs2tracker_trans : (p, 3) float, mm, tracker frame
    d_max : float, mm, longest distance searched by the fallback
    max_newton : int, Newton iterations before a beam falls back to the scan and Brent's method

    Returns
    -------
    BeamHits
    """
    zero = np.asarray(zero, float)
    u = np.asarray(direction, float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    R = np.asarray(tcs2tracker_rot, float).reshape(-1, 3, 3)
    T = np.asarray(tcs2tracker_trans, float).reshape(-1, 3)
    a = np.einsum("pij,nj->pni", R, zero) + T[:, None, :]
    b = np.einsum("pij,nj->pni", R, u)
    # start: the reference-plane intersection (h = 0)
    nb = b @ surface.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        d = -((a - surface.origin) @ surface.normal) / nb
    d = np.where(np.isfinite(d), d, 0.0)
    done = np.zeros(d.shape, bool)
    for _ in range(max_newton):
        f, df = _residual(surface, a, b, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.where(done, 0.0, f / df)
        ok = np.isfinite(step)
        d = np.where(ok, d - step, d)
        done |= ok & (np.abs(step) <= CAST_TOL_MM)
        if done.all():
            break
    for idx in zip(*np.nonzero(~done)):
        d[idx] = _bracket(surface, a[idx], b[idx], d_max)
    s, t, _ = surface.plane_coords(a + d[..., None] * b)
    valid = np.isfinite(d) & (d >= 0) & surface.inside(s, t)
    d = np.where(valid, d, np.nan)
    spot = a + d[..., None] * b
    m = surface.normal_at(np.where(valid, s, 0.0), np.where(valid, t, 0.0))
    cos = np.abs(np.sum(m * b, axis=-1))
    sin = np.linalg.norm(np.cross(m, b), axis=-1)
    inc = np.where(valid, np.arctan2(sin, cos), np.nan)  # accurate near 0, unlike arccos
    return BeamHits(d, inc, spot, valid)

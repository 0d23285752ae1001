"""The spins a redundant reading admits, and how far the tilt moves across them (the alias of a convention).

A 4-sensor head's one redundant combination of readings, fitted with the CAD's local surface turned by a spin
``psi`` about the tool axis, misses it by ``rho(psi)``; the shape operator's quadratic part turned by ``psi`` moves
as ``cos 2 psi`` and ``sin 2 psi``, so ``rho(psi) = A + B cos 2 psi + C sin 2 psi`` and the tilt likewise, each
component ``a + b cos 2 psi + c sin 2 psi``: three fits, at 0, 45 and 90 deg, give them per hole. The misfit then
takes its value at the convention (``psi = 0``) at a second spin too, ``2 psi = phi +- acos(-A / R)`` with
``R = hypot(B, C)``, ``phi = atan2(C, B)``: one scalar refutes a spin, it never confirms one. Where the head is not
symmetric, the tilt at that alias differs from the convention's (benchmarks/results/spin_convention_calibrated.md).

:func:`alias_reach` finds, per hole, the spin the reading admits (``|rho| <= sigmas sd``) whose tilt lies farthest
from the tilt within the convention's ``+-spin`` (the nearer end): the two roots, the misfit's least point and a
grid of :data:`GRID_DEG` (a reading blind to the spin admits the whole half-turn). The rule that reads it
(:data:`metrology.measure.spin.SPIN_ALIAS_SHARE`) lives with the other spin rules.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GRID_DEG", "harmonic", "alias_reach"]

#: deg: the grid over the half-turn on which the admitted spins are sought beside the misfit's roots (an arc narrower
#: than this is found through its root)
GRID_DEG = 1.0


def harmonic(v0, v45, v90):
    """``(a, b, c)`` of ``v(psi) = a + b cos 2 psi + c sin 2 psi`` from its values at 0, 45 and 90 deg (any shape)."""
    a = 0.5 * (v0 + v90)
    return a, v0 - a, v45 - a


def _at(abc, psi):
    """``a + b cos 2 psi + c sin 2 psi``: ``abc`` of (h,) or (h, 2) arrays, ``psi`` (h,) rad."""
    a, b, c = abc
    c2, s2 = np.cos(2 * psi), np.sin(2 * psi)
    if a.ndim == 2:
        c2, s2 = c2[:, None], s2[:, None]
    return a + b * c2 + c * s2


def alias_reach(rho, tilt, sd, sigmas, spin):
    """``(psi, reach)``: per hole, the admitted spin (h,) rad in ``[-90, 90)`` deg whose tilt is farthest from the
    tilt at the nearer end of ``+-spin``, and that distance (h,) rad (0 where every admitted spin lies within
    ``+-spin``, ``psi`` then NaN).

    Parameters
    ----------
    rho : three (h,) float, mm, the misfit fitted at the spins 0, 45 and 90 deg
    tilt : three (h, 2) float, rad, TCS, the tilt fitted there
    sd : (h,) float, mm, the misfit's sd (noise and calibration; the spin's doubt not in it)
    sigmas : float, the misfits admitted: ``|rho(psi)| <= sigmas sd``
    spin : (h,) float, rad, the convention's half-width
    """
    R = harmonic(*rho)
    T = harmonic(*tilt)
    A, B, C = R
    amp = np.hypot(B, C)
    phi = np.arctan2(C, B)
    with np.errstate(invalid="ignore", divide="ignore"):
        arc = np.arccos(np.clip(-A / np.where(amp > 0, amp, np.inf), -1.0, 1.0))
    h = len(A)
    least = phi + np.where(A > 0, np.pi, 0.0)  # 2 psi of the misfit's least |rho|
    cands = [0.5 * (phi + arc), 0.5 * (phi - arc), 0.5 * least]
    cands += [np.full(h, g) for g in np.radians(np.arange(-90.0, 90.0, GRID_DEG))]
    best, where = np.zeros(h), np.full(h, np.nan)
    for psi in cands:
        psi = (psi + 0.5 * np.pi) % np.pi - 0.5 * np.pi
        with np.errstate(invalid="ignore"):
            ok = (np.abs(_at(R, psi)) <= sigmas * sd) & (np.abs(psi) > spin)
        d = _at(T, psi) - _at(T, np.clip(psi, -spin, spin))
        n = np.where(ok, np.sqrt((d * d).sum(1)), 0.0)
        more = n > best
        best, where = np.where(more, n, best), np.where(more, psi, where)
    return where, best


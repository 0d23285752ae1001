"""Rule 2b's alternative (:mod:`metrology.measure.rules`): on a 4-sensor head without the panel, the tilt a
hole's redundant misfit would give were it one sensor's offset, not the panel's curvature.

One redundant reading gives one number, the misfit ``rho``. A panel of radius >= R within the bound
(``|rho| <= |M|_* / (2 R)``) and one sensor's offset ``delta_k = rho / (d rho / d delta_k)`` (a burr, a
sealant dot, a chip under its spot, the same before and after) give the same ``rho``; the curvature biases
the tilt little (the budget's curvature term holds it), the offset by as much as the plane through the
other three sensors differs from the four's. That difference, the largest over the sensors, is the edge
a U95 must add (to the three sensors' own) to cover both readings of the misfit.
"""

from __future__ import annotations

import numpy as np

from metrology.measure.estimator import PLANE_STEPS, fit_tilt
from metrology.measure.normals import hole_normals

__all__ = ["one_sensor_u95"]


def one_sensor_u95(layout, d, normal, U95) -> np.ndarray:
    """(h,) float, rad: a U95 that covers a hole's angle whether its misfit is the panel's or one sensor's offset:
    ``max(U95, edge + U95_3)``, ``edge`` the largest angle, over the sensors, between the hole's normal and the
    normal of the plane through the other three sensors' spots, ``U95_3`` that plane's own (its reading noise and
    calibration: the offset's reading is the misfit, the panel flat to it).

    Parameters
    ----------
    layout : SensorLayout, 4 sensors (the ones read at these holes)
    d : (h, 4) float, mm, finite readings
    normal : (h, 3) float, unit, TCS, the hole's normal from all four (:func:`metrology.measure.normals.hole_normals`)
    U95 : (h,) float, rad, its U95
    """
    d = np.asarray(d, float)
    edge = np.full(len(d), -1.0)
    worst = np.zeros(len(d), int)
    for k in range(layout.n):
        dk = d.copy()
        dk[:, k] = np.nan  # the plane through the other three (a blank is left out of the fit)
        nk = fit_tilt(layout, dk, None, PLANE_STEPS, full=False).normal
        ek = np.arctan2(np.linalg.norm(np.cross(normal, nk), axis=1), np.abs((normal * nk).sum(1)))
        worst = np.where(ek > edge, k, worst)
        edge = np.fmax(edge, ek)
    out = np.asarray(U95, float).copy()
    # the plane of the largest edge is fitted again for its U95, on its own 3-sensor layout: a subset layout
    # renormalises its beams (the last bit of a calibrated direction moves), so the edge's fit on the four's
    # layout, one reading blank, is not that fit to the bit; and the full fit of every plane, to fit each once,
    # costs more than this refit of one (measured: 12 % more CPU here, 16384 holes)
    for k in np.unique(worst).tolist():  # each hole once: the three sensors of its largest edge
        rows = np.flatnonzero(worst == k)
        keep = [j for j in range(layout.n) if j != k]
        three = hole_normals(layout.subset([layout.names[j] for j in keep]), d[np.ix_(rows, keep)])
        out[rows] = np.fmax(out[rows], edge[rows] + three.U95)
    return out

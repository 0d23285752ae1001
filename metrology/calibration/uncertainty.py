"""What the parameters' uncertainty does to the measured normal at the working stand-off.

The *working pose* is the datum perpendicular to the tool axis with the sensors' mean reading
equal to the working stand-off. If sensor ``i`` is really off its calibrated values by
``dtheta`` (chart ``(x, y, z, a, b)``, mm and rad), its readings there are those of the true
sensor while the normal is computed with the calibrated one; to first order the measured
normal tilts by ``G dtheta`` (two angles, rad, about two axes perpendicular to the true
normal). With the chart covariance ``C`` (block diagonal over the sensors: each sensor is
fitted from its own readings) the normal's covariance is ``G C G^T`` and its predicted
1-sigma is ``sqrt(trace(G C G^T))``, the RMS angle between measured and true normal.
"""

from __future__ import annotations

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis, direction_from_tangent, readings
from metrology.core.normals import micro_plane_normal

__all__ = ["tool_axis", "working_plane", "normal_sensitivity", "normal_sigma", "residual_scaled_cov"]

#: step of the central differences of the normal w.r.t. the chart parameters (mm and rad)
_STEP = 1e-6


def tool_axis(layout: SensorLayout) -> np.ndarray:
    """(3,) float, unit, TCS: the TCS z axis signed to point the way the beams go.

    Raises ValueError when a beam points more than 84 deg away from it (no pose puts every
    spot on a datum facing the tool).
    """
    sign = 1.0 if np.mean(layout.direction[:, 2]) > 0 else -1.0
    axis = np.array([0.0, 0.0, sign])
    if np.min(layout.direction @ axis) <= 0.1:
        raise ValueError("every beam must point within 84 deg of the tool axis (TCS z)")
    return axis


def working_plane(layout: SensorLayout, standoff_mm: float):
    """The datum perpendicular to the tool axis at which the mean reading is ``standoff_mm``.

    Returns
    -------
    normal : (1, 3) float, unit, TCS (the tool axis)
    offset : (1,) float, mm
    """
    a = tool_axis(layout)
    c = layout.direction @ a  # reading d_i on {a . p = h}: (h - a . E_i) / c_i
    h = (float(standoff_mm) + np.mean((layout.zero @ a) / c)) / np.mean(1.0 / c)
    return a[None], np.array([-h])


def _normal(layout, zero, direction, normal, offset):
    d, _ = readings(zero, direction, normal, offset)
    return micro_plane_normal(layout.zero, layout.direction, d)[0]


def normal_sensitivity(layout: SensorLayout, standoff_mm: float) -> np.ndarray:
    """Tilt of the measured normal per unit error of every chart parameter.

    Parameters
    ----------
    layout : SensorLayout, the calibrated (or nominal) layout; the chart is centred on it
    standoff_mm : float, mm, the working stand-off (mean reading)

    Returns
    -------
    G : (2, n, 5) float, rad per mm (x, y, z) and rad per rad (a, b)
        The two tilt angles, about axes perpendicular to the working normal.
    """
    N, D = working_plane(layout, standoff_mm)
    n0 = _normal(layout, layout.zero, layout.direction, N, D)
    e = direction_basis(n0[None])[0]  # (2, 3)
    G = np.zeros((2, layout.n, 5))
    for i in range(layout.n):
        for k in range(5):
            cols = []
            for step in (_STEP, -_STEP):
                theta = np.zeros(5)
                theta[k] = step
                zero = layout.zero.copy()
                direction = layout.direction.copy()
                zero[i] += theta[:3]
                direction[i] = direction_from_tangent(layout.direction[i][None], theta[None, 3:])[0]
                cols.append(e @ _normal(layout, zero, direction, N, D))
            G[:, i, k] = (cols[0] - cols[1]) / (2 * _STEP)
    return G


def normal_sigma(G, cov) -> float:
    """Predicted 1-sigma (rad) of the measured normal: ``sqrt(trace(G C G^T))``.

    Parameters
    ----------
    G : (2, n, 5) float, from :func:`normal_sensitivity`
    cov : (n, 5, 5) float, mm and rad, chart covariance per sensor

    Returns
    -------
    float, rad; inf when a covariance is not finite (a parameter not determined)
    """
    cov = np.asarray(cov, float)
    if not np.all(np.isfinite(cov)):
        return float("inf")
    C = np.einsum("ain,nij,bjn->ab", G.transpose(0, 2, 1), cov, G.transpose(0, 2, 1))
    return float(np.sqrt(max(np.trace(C), 0.0)))


def residual_scaled_cov(J, residuals):
    """The standard errors metro reports: the chart covariance scaled by the readings' own scatter.

    ``s^2 = sum r^2 / (m - 5)`` (the stated noise times the root of the reduced chi-square) and
    ``C = s^2 (J^T J)^-1``, no prior: what ``calibrate`` (least squares) reports, the precision
    verdict and the stopping rule of ``calibrate --follow`` use. Residuals above the stated
    noise (a model that misses something) widen the sigma; below it, they narrow it.

    Parameters
    ----------
    J : (m, 5) float, mm per mm and mm per rad, the Jacobian of the readings at the estimate
    residuals : (m,) float, mm, measured minus predicted readings at the estimate

    Returns
    -------
    s : float, mm, the scatter (inf when m <= 5: no redundancy to measure it)
    cov : (5, 5) float, mm and rad, symmetric; all inf when ``s`` or ``J^T J`` is not usable
    """
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    J, r = np.asarray(J, float), np.asarray(residuals, float)
    m, p = J.shape
    bad = np.full((p, p), np.inf)
    if m <= p:
        return float("inf"), bad
    s2 = float(r @ r) / (m - p)
    try:
        cov = cho_solve(cho_factor(J.T @ J), np.eye(p)) * s2
    except LinAlgError:
        return float(np.sqrt(s2)), bad
    return float(np.sqrt(s2)), (cov + cov.T) / 2

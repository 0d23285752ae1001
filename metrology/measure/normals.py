"""Each hole's normal, its angle to the drill axis and their first-order (GUM) uncertainty.

At a drilling point the cell reads its sensors; the projection points ``S_i = E_i + d_i u_i``
(Eq. 17, mm, TCS) lie on the panel. metro fits the micro-plane through them by weighted least
squares as a graph over the TCS ``xy`` plane,

    z = c + g_x x + g_y y,        n = +-(-g_x, -g_y, 1) / sqrt(1 + g_x^2 + g_y^2),

each point weighted by ``1 / (sigma_i u_z,i)^2``, its reading noise along the drill axis
(:mod:`metrology.measure.estimator`, the panel path's estimator too). With 3 sensors it is the plane
through the points; with 4 it departs from the paper's Eqs. 18-19, which weigh the four corners alike
(they stay in :mod:`metrology.core.normals`): a noisier sensor weighs less, which lowers the angle's
error (the module above says by how much). It orients ``n`` along the drill axis (the TCS ``z`` axis signed the way
the beams point, ``n . axis > 0``): the direction the cell turns the drill onto (Eqs. 20-22).
The angle between the drill axis and the normal is ``alpha = atan(|g|)``.

**Uncertainty.** To first order only the displacement of each point along the normal matters:
with ``m = (-g_x, -g_y, 1)`` and ``h_i = m . dS_i``, ``dg = P h`` where ``P`` (2, n) is the
weighted least-squares map from heights to slopes. A reading error moves ``S_i`` by ``u_i dd_i``; a
calibration error by ``dE_i + d_i (a e1_i + b e2_i)`` (the chart of
:mod:`metrology.core.model`, centred on the calibrated beam). So

    Sigma_g = sum_i sigma_i^2 (m.u_i)^2 P_i P_i^T  +  J_theta C J_theta^T,

with ``C`` the layout's ``covariance`` (5n, 5n) and ``J_theta`` row blocks
``P_i (m, d_i m.e1_i, d_i m.e2_i)``. The angle's standard uncertainty is
``sqrt(c^T Sigma_g c)`` with ``c = g / (|g| (1 + |g|^2))`` and its expanded uncertainty
``U95 = K95 u`` (:data:`K95`, normal distribution). Near ``alpha = 0`` (after the cell's
adjustment) the angle is the length of the 2-D tilt, not normal: U95 is then the half-width
holding 95 % of that length (:func:`metrology.measure.magnitude.magnitude_u95`, the same rule as
with the panel known), up to ``X_MAX`` of the tilt's major-axis standard deviations.

**Curvature.** On a curved panel the spots do not lie on the tangent plane at the drill point
(where the drill axis meets the panel): near it the panel is ``h = r^T K r / 2`` (``r`` the
offset from the drill axis, ``K`` the curvature tensor), and the plane through the spots tilts by
``dg = sum_i P_i r_i^T K r_i / 2``: the spots' centroid is off the axis (the beams are inclined,
so a tilted panel moves the spots along them) and they form a trapezoid. metro does not know
``K`` at a hole; given the panel's smallest radius ``R_min`` and that it curves one way (convex or
concave: a cylinder, a sphere, a doubly-curved skin; ``K`` semidefinite with eigenvalues within
``1 / R_min``, any orientation) the angle's bias lies within ``+-b``,

    b = max(sum of the positive, -sum of the negative eigenvalues of M) / (2 R_min),
    M = sum_i w_i r_i r_i^T                              (w_i = d alpha / d h_i)

the exact worst case, entered as a rectangular distribution, ``u_b = b / sqrt(3)`` (GUM 4.3.7).
Near ``alpha = 0`` (below :data:`SMALL_ANGLE_SIGMAS`) the bound enters the tilt's covariance as
a round spread of the same variance per axis, and U95 is the length's half-width of the sum;
beyond, ``K95 u`` as above. It stays a worst case: U95 with it over-covers every panel flatter
than ``R_min`` (99-100 % on spheres and cylinders of exactly ``R_min``).
On a flat panel (``min_radius_mm = inf``) ``b = 0``. A saddle (principal curvatures of both
signs) can tilt the plane further, by up to the nuclear norm of ``M`` over ``2 R_min``.

**Redundancy.** With ``n >= 4`` points the fit has ``n - 3`` residual degrees of freedom. For
4 points the residual is one number, ``rho = q . z`` (mm, ``q`` the unit vector orthogonal to
``1, x, y``): the misfit of the redundant reading to the micro-plane. To first order
``d rho = q . h``, so its standard deviation from reading noise alone is
``sqrt(sum_i q_i^2 (m.u_i)^2 sigma_i^2)``, and ``z = rho / that`` is N(0, 1) while every
sensor holds its calibration; a zero shift ``delta`` of sensor ``k`` moves ``rho`` by
``q_k (m.u_k) delta``. For more points :func:`hole_normals` gives the residual's RMS and its
chi-square over the noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.core.sym2 import nuclear2, one_sign2
from metrology.measure.budget import CURVATURE, READING_NOISE, SMALL_ANGLE_SIGMAS, Budget, Kind, Source, angle_gradient, combine
from metrology.measure.estimator import PLANE_STEPS, drill_axis, fit_tilt, rows_dot
from metrology.measure.magnitude import K95
from metrology.measure.terms import reading_sigma, reading_sources, redundancy

__all__ = ["HoleNormals", "hole_normals", "concat_normals", "drill_axis", "K95", "K95_2D", "SMALL_ANGLE_SIGMAS"]

#: radius, in standard deviations, of the 95 % disc of an isotropic 2-D normal: sqrt(chi2_2(0.95))
K95_2D = 2.447746830680816


@dataclass(frozen=True)
class HoleNormals:
    """Normals of holes measured with one set of sensors.

    Attributes
    ----------
    normal : (N, 3) float, unit, TCS, along the drill axis (``n . axis > 0``)
    angle : (N,) float, rad, between the drill axis and ``normal``
    u_angle : (N,) float, rad, standard uncertainty of ``angle`` (reading noise + calibration)
    U95 : (N,) float, rad, expanded uncertainty (95 %) of ``angle``
    u_angle_noise : (N,) float, rad, the reading noise's share of ``u_angle``
    residual : (N,) float, mm; 4 sensors: the signed misfit ``rho``; 5+: the RMS misfit of the
        points to their plane; 3: NaN (no redundancy)
    residual_z : (N,) float; 4 sensors: ``rho`` over its noise sigma, N(0, 1) in control; 5+:
        ``sqrt(chi2 / (n - 3))`` of the misfit over the noise; 3: NaN
    signature : (N, n) float, mm/mm, or None; 4 sensors: ``d rho / d delta_k``, how a zero shift
        of each sensor moves ``rho``
    curvature_bound : (N,) float, rad, ``b``: the largest bias of ``angle`` a panel of radius
        ``min_radius_mm`` gives (0 on a flat panel); ``u_angle`` includes ``b / sqrt(3)``
    twist : (N,) float, mm^2, or None; 4 sensors: ``||sum_i q_i r_i r_i^T||_*``: a panel of
        principal radii >= R moves ``rho`` by at most ``twist / (2 R)`` (any shape, saddles too)
    residual_noise_sd : (N,) float, mm, or None; 4 sensors: the standard deviation of ``rho`` from
        the reading noise alone (``residual / residual_z``)
    residual_sd : (N,) float, mm, or None; 4 sensors: the standard deviation of ``rho`` from the
        reading noise and the calibration's uncertainty (its per-sensor blocks): how far from 0 a
        head within its calibration puts the redundant reading
    budget : Budget, the tilts and their covariance by source (:mod:`metrology.measure.budget`), from
        which ``angle``, ``u_angle``, ``U95`` and ``u_angle_noise`` were made
    misfit_bound : (N,) float, mm, or None; 4 sensors with the panel known: the most what is not known of
        the panel (the direction of its curvature where the head's spin is not) moves ``rho`` (None: the
        micro-plane's ``twist / (2 R)``)
    moment : (N, 3) float, mm^2, or None; 4 sensors, the micro-plane: ``M = sum_i q_i r_i r_i^T`` as
        (xx, yy, xy), whose nuclear norm is ``twist`` (a panel of curvature ``K`` moves ``rho`` by
        ``tr(K M) / 2``; rule 3 compares it before and after the adjustment)
    """

    normal: np.ndarray
    angle: np.ndarray
    u_angle: np.ndarray
    U95: np.ndarray
    u_angle_noise: np.ndarray
    residual: np.ndarray
    residual_z: np.ndarray
    signature: np.ndarray | None
    curvature_bound: np.ndarray | None = None
    twist: np.ndarray | None = None
    residual_sd: np.ndarray | None = None
    residual_noise_sd: np.ndarray | None = None
    budget: Budget | None = None
    misfit_bound: np.ndarray | None = None
    moment: np.ndarray | None = None


def concat_normals(parts) -> "HoleNormals":
    """The holes of ``parts`` (:class:`HoleNormals` of the same sensors) one after the other."""
    if len(parts) == 1:
        return parts[0]
    first = parts[0]

    def join(f):
        v = getattr(first, f)
        if v is None:
            return None
        return Budget.concat([p.budget for p in parts]) if f == "budget" else np.concatenate([getattr(p, f) for p in parts])

    return HoleNormals(**{f: join(f) for f in first.__dataclass_fields__})


def hole_normals(layout: SensorLayout, d, covariance=None, sigma_mm=None, min_radius_mm=np.inf) -> HoleNormals:
    """Normals, angles and uncertainties of holes whose every reading is present.

    Parameters
    ----------
    layout : SensorLayout, n >= 3 sensors (the ones read at these holes)
    d : (N, n) float, mm, finite readings
    covariance : (5n, 5n) float, mm and rad, or None: the calibration's covariance (the layout's
        ``covariance`` by default; None there too: the calibration's share is left out)
    sigma_mm : (n,) float, mm, reading noise (default: the layout's ``noise_mm``)
    min_radius_mm : float, mm, the panel's smallest radius (inf: flat), for the curvature term

    Returns
    -------
    HoleNormals

    The fit is :func:`metrology.measure.estimator.fit_tilt` without a shape (the estimator of the panel
    path too), its budget's reading noise and calibration :func:`metrology.measure.terms.reading_sources`.
    """
    n = layout.n
    d = np.asarray(d, dtype=float).reshape(-1, n)
    N = len(d)
    cov = layout.covariance if covariance is None else np.asarray(covariance, float)
    sigma = reading_sigma(layout, sigma_mm)
    fit = fit_tilt(layout, d, None, PLANE_STEPS, sigma_mm)
    if not fit.ok.all():
        raise ValueError("the projection points of a hole are collinear: no plane")
    dT = np.ascontiguousarray(d.T)
    A0, A1, Gu, noise, cal, q_cal = reading_sources(layout, fit, dT, cov, sigma)
    gx, gy = fit.g[:, 0], fit.g[:, 1]
    x, y = fit.spots  # (n, N), mm, TCS: the spots
    # the spots' second moments (n, N) each, read by the curvature bound and the misfit's moment alike
    xx, xy, yy = (x * x, x * y, y * y) if np.isfinite(min_radius_mm) or n == 4 else (None, None, None)
    # the curvature bias bound: the worst one-signed quadric panel of radii >= min_radius_mm along the
    # angle's gradient; near 0, a round spread of the rectangular variance per axis (a worst case), stated
    # in angle (rad^2): the budget's slopes^2 are that times (1 + |g|^2)^2
    curve = np.zeros((N, 3))
    if np.isfinite(min_radius_mm):
        g2 = gx * gx + gy * gy
        cx, cy = angle_gradient(gx, gy)
        m0, m1 = _moments(A0, xx, xy, yy), _moments(A1, xx, xy, yy)  # sum_i A_i r_i r_i^T of each slope
        bound = one_sign2(*(cx * a + cy * b for a, b in zip(m0, m1))) / (2.0 * min_radius_mm)  # linear in A
        b2 = (one_sign2(*m0) ** 2 + one_sign2(*m1) ** 2) / (2.0 * min_radius_mm) ** 2 / 3.0
        curve[:, 0] = curve[:, 2] = b2 * (1.0 + g2) ** 2
    else:
        bound = np.zeros(N)
    budget = Budget(fit.g.copy(), (noise, cal, Source(CURVATURE, curve, Kind.BOUND, bound)))
    un = combine(budget)
    if n == 4:
        q = fit.null.T  # (4, N), unit, orthogonal to 1, x, y
        red = redundancy(q, fit.h_res.T, Gu, sigma, q_cal)
        mxx, mxy, myy = _moments(q, xx, xy, yy)  # q is orthogonal to 1, x, y: the spots' centroid drops out
        moment = np.stack([mxx, myy, mxy], axis=1)
        twist = nuclear2(mxx, mxy, myy)
    else:
        red = redundancy(None, fit.h_res.T, Gu, sigma, q_cal)
        twist = moment = None
    return HoleNormals(-fit.normal, un.angle, un.u, un.U95, un.of(READING_NOISE), red.residual, red.residual_z,
                       red.signature, bound, twist, red.sd, red.noise_sd, budget, moment=moment)


def _moments(w, xx, xy, yy):
    """``sum_i w_i r_i r_i^T`` as its entries ``(xx, xy, yy)``, (N,) each (``w`` and the spots' products (n, N))."""
    return rows_dot(w, xx), rows_dot(w, xy), rows_dot(w, yy)


def _null_vector_4(xc, yc):
    """(4, N) unit vectors orthogonal to ``1, x, y`` of 4 points (``xc, yc`` (4, N)): the signed
    cofactors ``det [1 x y]`` of the other three rows (twice the signed area of their triangle)."""
    def area2(a, b, c):
        return (xc[b] - xc[a]) * (yc[c] - yc[a]) - (xc[c] - xc[a]) * (yc[b] - yc[a])

    q = np.stack([area2(1, 2, 3), -area2(0, 2, 3), area2(0, 1, 3), -area2(0, 1, 2)], axis=0)
    return q / np.sqrt((q * q).sum(0))

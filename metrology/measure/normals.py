"""Each hole's normal, its angle to the drill axis and their first-order (GUM) uncertainty.

At a drilling point the cell reads its sensors; the projection points ``S_i = E_i + d_i u_i``
(Eq. 17, mm, TCS) lie on the panel. metro fits the micro-plane through them by least squares
as a graph over the TCS ``xy`` plane,

    z = c + g_x x + g_y y,        n = +-(-g_x, -g_y, 1) / sqrt(1 + g_x^2 + g_y^2),

(the plane through the points for 3 sensors; for 4 it agrees with Eqs. 18-19 to first order in
the points' misfit) and orients ``n`` along the drill axis (the TCS ``z`` axis signed the way
the beams point, ``n . axis > 0``): the direction the cell turns the drill onto (Eqs. 20-22).
The angle between the drill axis and the normal is ``alpha = atan(|g|)``.

**Uncertainty.** To first order only the displacement of each point along the normal matters:
with ``m = (-g_x, -g_y, 1)`` and ``h_i = m . dS_i``, ``dg = P h`` where ``P`` (2, n) is the
least-squares map from heights to slopes. A reading error moves ``S_i`` by ``u_i dd_i``; a
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
from metrology.core.model import direction_basis
from metrology.measure.magnitude import K95, X_MAX, magnitude_u95, major_sd

__all__ = ["HoleNormals", "hole_normals", "drill_axis", "radius95", "K95", "K95_2D", "SMALL_ANGLE_SIGMAS"]

#: radius, in standard deviations, of the 95 % disc of an isotropic 2-D normal: sqrt(chi2_2(0.95))
K95_2D = 2.447746830680816
#: below this many standard uncertainties the angle's distribution is not close to normal (it is
#: the length of a 2-D vector): u is the 2-D spread's major axis (and, with the curvature bound,
#: U95 the length's half-width instead of the linear rule)
SMALL_ANGLE_SIGMAS = 4.0


def drill_axis(layout: SensorLayout) -> np.ndarray:
    """(3,) float, unit, TCS: the TCS ``z`` axis signed the way the beams point (the drill axis)."""
    return np.array([0.0, 0.0, 1.0 if np.mean(layout.direction[:, 2]) > 0 else -1.0])


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


def _chart_rows(layout: SensorLayout):
    """(n, 2, 3): the chart axes e1, e2 of each calibrated beam."""
    return direction_basis(layout.direction)


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
    """
    n = layout.n
    d = np.asarray(d, dtype=float).reshape(-1, n)
    N = len(d)
    cov = layout.covariance if covariance is None else np.asarray(covariance, float)
    sigma = layout.noise_mm if sigma_mm is None else np.broadcast_to(np.asarray(sigma_mm, float), (n,))
    sigma = np.where(np.isfinite(sigma), sigma, 0.0)[:, None]
    E, u = layout.zero, layout.direction
    # sensor-major (n, N) arrays: a sum over the sensors is a sum of contiguous rows
    dT = np.ascontiguousarray(d.T)
    x = E[:, 0, None] + dT * u[:, 0, None]  # projection points, mm, TCS
    y = E[:, 1, None] + dT * u[:, 1, None]
    z = E[:, 2, None] + dT * u[:, 2, None]
    xc, yc, zc = x - x.mean(0), y - y.mean(0), z - z.mean(0)
    sxx, syy, sxy = (xc * xc).sum(0), (yc * yc).sum(0), (xc * yc).sum(0)
    sxz, syz = (xc * zc).sum(0), (yc * zc).sum(0)
    det = sxx * syy - sxy * sxy
    if np.any(det <= 0):
        raise ValueError("the projection points of a hole are collinear: no plane")
    gx = (syy * sxz - sxy * syz) / det
    gy = (sxx * syz - sxy * sxz) / det
    # P_i: the slopes' change per unit height of point i
    px = (syy * xc - sxy * yc) / det
    py = (sxx * yc - sxy * xc) / det
    axis = drill_axis(layout)
    g2 = gx * gx + gy * gy
    gn = np.sqrt(g2)
    r = np.sqrt(1.0 + g2)
    normal = np.stack([-gx, -gy, np.ones_like(gx)], axis=1) * (axis[2] / r)[:, None]
    angle = np.arctan(gn)
    mu = u[:, 2, None] - gx * u[:, 0, None] - gy * u[:, 1, None]  # m . u_i
    # the slopes' covariance (2, 2) per hole: reading noise and the calibration
    qn = (mu * sigma) ** 2  # each point's height variance from its reading noise
    noise_g = _spread(px, py, qn)
    cal_g, q_cal = _calibration_cov(layout, cov, dT, px, py, gx, gy) if cov is not None else (None, 0.0)
    # the angle: c = d alpha / d g
    with np.errstate(invalid="ignore", divide="ignore"):
        k = 1.0 / (gn * (1.0 + g2))
    k = np.where(np.isfinite(k), k, 0.0)
    cx, cy = gx * k, gy * k
    var_noise = _quad(cx, cy, noise_g)
    var = var_noise + (_quad(cx, cy, cal_g) if cal_g is not None else 0.0)
    # the curvature bias bound: the worst one-signed quadric panel of radii >= min_radius_mm
    flat = not np.isfinite(min_radius_mm)
    bound = np.zeros(N) if flat else _one_sign(cx * px + cy * py, x, y) / (2.0 * min_radius_mm)
    var = var + bound ** 2 / 3.0
    u_angle = np.sqrt(var)
    U95 = K95 * u_angle
    # near alpha = 0 the angle is the length of the 2-D tilt: u is the 2-D spread's major axis, and
    # U95 the half-width holding 95 % of the tilt's length (metrology.measure.magnitude); the linear
    # rule beyond X_MAX major-axis standard deviations
    tot = [noise_g[j] + (cal_g[j] if cal_g is not None else 0.0) for j in range(3)]
    scale = (1.0 + g2) ** 2
    Ca = np.empty((N, 2, 2))
    Ca[:, 0, 0], Ca[:, 0, 1], Ca[:, 1, 1] = tot[0] / scale, tot[1] / scale, tot[2] / scale
    Ca[:, 1, 0] = Ca[:, 0, 1]
    if not flat:  # the curvature bound, as a round spread of the rectangular variance (a worst case)
        b2 = (_one_sign(px, x, y) ** 2 + _one_sign(py, x, y) ** 2) / (2.0 * min_radius_mm) ** 2 / 3.0
        Ca[:, 0, 0] += b2
        Ca[:, 1, 1] += b2
    s2d = major_sd(Ca)  # rad: the major axis's standard deviation
    still = (angle < SMALL_ANGLE_SIGMAS * 2.0 * u_angle) & (angle < SMALL_ANGLE_SIGMAS * s2d)
    u_angle[still] = s2d[still]
    # with the curvature bound (a worst case, not a distribution) the half-width is taken only where
    # the 2-D radius was (below SMALL_ANGLE_SIGMAS): beyond, the bound's exact worst case along the
    # angle's gradient (rectangular, in u) stays as it is
    near = angle < X_MAX * s2d if flat else still
    if np.any(near):
        with np.errstate(invalid="ignore", divide="ignore"):
            tilt = np.stack([gx, gy], axis=1)[near] * np.where(gn[near] > 0, angle[near] / gn[near], 1.0)[:, None]
        U95[near] = magnitude_u95(tilt, Ca[near])
    residual = np.full(N, np.nan)
    residual_z = np.full(N, np.nan)
    signature = twist = residual_sd = sd = None
    if n == 4:
        q = _null_vector_4(xc, yc)  # (4, N), unit, orthogonal to 1, x, y
        residual = (q * zc).sum(0)
        sig = q * mu  # d rho / d delta_k
        sd = np.sqrt(((sig * sigma) ** 2).sum(0))
        with np.errstate(invalid="ignore", divide="ignore"):
            residual_z = residual / sd
        residual_sd = np.sqrt(sd * sd + (q * q * q_cal).sum(0))  # the calibration's own blocks added
        signature = np.ascontiguousarray(sig.T)
        twist = _nuclear(q, xc, yc)
    elif n > 4:
        res = zc - gx * xc - gy * yc
        residual = np.sqrt((res * res).sum(0) / n)
        v = (mu * sigma) ** 2
        with np.errstate(invalid="ignore", divide="ignore"):
            residual_z = np.sqrt((res * res / v).sum(0) / (n - 3))
    return HoleNormals(normal, angle, u_angle, U95, np.sqrt(var_noise), residual, residual_z, signature, bound, twist,
                       residual_sd, sd)


def _radius_table():
    """``f(r)`` on a grid of ``r = l2 / l1`` in [0, 1]: ``P(Z1^2 + r Z2^2 <= f^2) = 0.95``, Z standard
    normal (the integral over ``Z2`` of the normal probability of ``Z1``, bisection in ``f``)."""
    from scipy.special import erf

    z = np.linspace(-8.0, 8.0, 4001)
    w = np.exp(-0.5 * z * z) / np.sqrt(2.0 * np.pi) * (z[1] - z[0])
    grid = np.linspace(0.0, 1.0, 101)
    out = np.empty_like(grid)
    for i, r in enumerate(grid):
        lo, hi = 1.9, 2.5
        for _ in range(50):
            f = 0.5 * (lo + hi)
            inside = np.clip(f * f - r * z * z, 0.0, None)
            p = np.sum(w * erf(np.sqrt(inside / 2.0)))
            lo, hi = (f, hi) if p < 0.95 else (lo, f)
        out[i] = 0.5 * (lo + hi)
    return grid, out


#: ``f`` of :func:`radius95` on the ratios 0, 0.01, ..., 1 (from :func:`_radius_table`, which
#: tests/measure/test_normals.py runs again)
RADIUS95_F = np.array([
    1.959964, 1.962530, 1.965125, 1.967751, 1.970408, 1.973097, 1.975819, 1.978576, 1.981368, 1.984196,
    1.987062, 1.989968, 1.992914, 1.995901, 1.998933, 2.002011, 2.005137, 2.008314, 2.011543, 2.014828,
    2.018172, 2.021576, 2.025045, 2.028580, 2.032184, 2.035859, 2.039607, 2.043430, 2.047329, 2.051305,
    2.055359, 2.059490, 2.063700, 2.067987, 2.072350, 2.076790, 2.081304, 2.085892, 2.090552, 2.095282,
    2.100078, 2.104943, 2.109872, 2.114859, 2.119913, 2.125020, 2.130180, 2.135398, 2.140663, 2.145980,
    2.151344, 2.156755, 2.162203, 2.167693, 2.173223, 2.178791, 2.184398, 2.190029, 2.195702, 2.201396,
    2.207121, 2.212874, 2.218654, 2.224461, 2.230296, 2.236131, 2.242012, 2.247889, 2.253792, 2.259718,
    2.265672, 2.271625, 2.277584, 2.283557, 2.289550, 2.295562, 2.301583, 2.307598, 2.313653, 2.319679,
    2.325738, 2.331801, 2.337858, 2.343931, 2.350026, 2.356117, 2.362201, 2.368294, 2.374393, 2.380498,
    2.386611, 2.392702, 2.398801, 2.404914, 2.411041, 2.417181, 2.423259, 2.429390, 2.435510, 2.441618,
    2.447771
])


def radius95(l1, l2):
    """The radius of the disc about the centre that holds 95 % of a 2-D normal distribution of
    eigenvalues ``l1 >= l2 >= 0`` (arrays): ``sqrt(l1) f(l2 / l1)``, ``f`` from 1.96 (a line) to
    :data:`K95_2D` (round), :data:`RADIUS95_F` on 101 ratios, interpolated (to 1e-4)."""
    grid, f = np.linspace(0.0, 1.0, len(RADIUS95_F)), RADIUS95_F
    l1 = np.asarray(l1, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(l1 > 0, np.asarray(l2, float) / l1, 1.0)
    return np.sqrt(l1) * np.interp(np.clip(r, 0.0, 1.0), grid, f)


def _height_rows(layout, dT, gx, gy):
    """(n, N, 5): a calibration error's effect on each point's height along ``m``,
    ``(m, d_i m.e1_i, d_i m.e2_i)`` for ``(x, y, z, a, b)`` of sensor i (sensor first: each
    sensor's rows are contiguous); ``dT (n, N)`` the readings."""
    e = _chart_rows(layout)  # (n, 2, 3)
    rows = np.empty(dT.shape + (5,))
    rows[..., 0] = -gx[None, :]
    rows[..., 1] = -gy[None, :]
    rows[..., 2] = 1.0
    for k in range(2):
        rows[..., 3 + k] = dT * (e[:, k, 2, None] - gx[None, :] * e[:, k, 0, None] - gy[None, :] * e[:, k, 1, None])
    return rows


def _spread(px, py, q):
    """The slopes' covariance ``(c00, c01, c11)`` of independent point heights of variance ``q (n, N)``."""
    return (px * px * q).sum(0), (px * py * q).sum(0), (py * py * q).sum(0)


def _quad(cx, cy, c):
    """``c^T Sigma c`` per row, ``Sigma = (c00, c01, c11)``."""
    return cx * cx * c[0] + 2 * cx * cy * c[1] + cy * cy * c[2]


def _calibration_cov(layout, cov, dT, px, py, gx, gy):
    """The slopes' covariance ``(c00, c01, c11)`` from the calibration's covariance ``cov (5n, 5n)``,
    and each point's height variance ``r_i^T C_ii r_i`` (n, N) from its own sensor's block.

    A calibration fits each sensor from its own readings, so ``cov`` is block diagonal: then the
    points are independent (fast); any other covariance is propagated whole."""
    n = layout.n
    rows = _height_rows(layout, dT, gx, gy)  # (n, N, 5)
    blocks = [cov[5 * i:5 * i + 5, 5 * i:5 * i + 5] for i in range(n)]
    off = cov.copy()
    for i in range(n):
        off[5 * i:5 * i + 5, 5 * i:5 * i + 5] = 0.0
    q = np.stack([np.einsum("pk,pk->p", rows[i] @ blocks[i], rows[i]) for i in range(n)], axis=0)
    if not np.any(off):
        return _spread(px, py, q), q
    N = dT.shape[1]
    sx = (rows * px[..., None]).transpose(1, 0, 2).reshape(N, -1)
    sy = (rows * py[..., None]).transpose(1, 0, 2).reshape(N, -1)
    cx, cy = sx @ cov, sy @ cov
    return (np.einsum("ij,ij->i", cx, sx), np.einsum("ij,ij->i", cx, sy), np.einsum("ij,ij->i", cy, sy)), q


def _one_sign(w, x, y):
    """(N,) ``max(sum of positive, -sum of negative eigenvalues)`` of ``sum_i w_i r_i r_i^T`` (2 x 2
    per hole; ``w, x, y`` (n, N)): the largest ``|tr(K M)|`` over semidefinite ``K`` of eigenvalues
    within 1."""
    a, b, c = (w * x * x).sum(0), (w * y * y).sum(0), (w * x * y).sum(0)
    disc = np.sqrt(0.25 * (a - b) ** 2 + c * c)
    l1, l2 = 0.5 * (a + b) + disc, 0.5 * (a + b) - disc
    return np.maximum(np.maximum(l1, 0) + np.maximum(l2, 0), -(np.minimum(l1, 0) + np.minimum(l2, 0)))


def _nuclear(w, x, y):
    """(N,) the nuclear norm of ``sum_i w_i r_i r_i^T`` (2 x 2 per hole; ``w, x, y`` (n, N))."""
    a, b, c = (w * x * x).sum(0), (w * y * y).sum(0), (w * x * y).sum(0)
    disc = np.sqrt(0.25 * (a - b) ** 2 + c * c)
    return np.abs(0.5 * (a + b) + disc) + np.abs(0.5 * (a + b) - disc)


def _null_vector_4(xc, yc):
    """(4, N) unit vectors orthogonal to ``1, x, y`` of 4 points (``xc, yc`` (4, N)): the signed
    cofactors ``det [1 x y]`` of the other three rows (twice the signed area of their triangle)."""
    def area2(a, b, c):
        return (xc[b] - xc[a]) * (yc[c] - yc[a]) - (xc[c] - xc[a]) * (yc[b] - yc[a])

    q = np.stack([area2(1, 2, 3), -area2(0, 2, 3), area2(0, 1, 3), -area2(0, 1, 2)], axis=0)
    return q / np.sqrt((q * q).sum(0))

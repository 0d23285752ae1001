"""A hole's normal measured with its panel's local surface known: the spots lie on a curved
surface, not on a plane.

At a drilling point the projection points ``S_i = E_i + d_i u_i`` (mm, TCS) lie on the panel.
Near the hole the panel is its tangent plane bent by its shape operator ``K`` (1/mm, TCS,
``k1 e1 e1^T + k2 e2 e2^T``, the principal directions ``e1, e2`` tangent to the surface, given
as for the head square to it: in the TCS ``xy`` plane; curvature positive where the surface bends
*away* from the head). metro fits the surface's pose, two tilts ``g = (g_x, g_y)`` and an offset
``c`` along the TCS ``z`` axis, with ``K`` known:

    h_i(g, c) = z_i - c - g_x x_i - g_y y_i + sigma rho kappa_i,
    kappa_i = 1/2 (T q_i)^T K_m (T q_i),   q_i = S_i - c e_z,   T = I - m m^T,
    m = sigma (-g_x, -g_y, 1) / rho,     rho = sqrt(1 + |g|^2),   K_m = Q K Q^T,

``Q`` the smallest rotation taking ``sigma e_z`` onto ``m`` (the shape turned with the tilted head),
``m`` the unit normal toward the head (``sigma = -s``, the drill axis ``s e_z``). ``h_i = 0`` is
the surface ``m.(p - c e_z) = -1/2 (Tq)^T K_m (Tq)`` (to second order in the distance from the axis;
``h_i`` is ``rho`` times the point's height over it along ``m``). With ``K = 0`` the fit is the
micro-plane of :mod:`metrology.measure.normals`, which is the first of :data:`GN_STEPS` steps;
the rest are Gauss-Newton steps with ``K`` (the Jacobian's ``c`` column carries the curvature's
slope; what is left out of it is of order ``|K| |m.q|``), weighted by the readings' noise along
the normal, vectorised over holes.

With 3 sensors the three readings fix the three unknowns (the curvature comes from the panel
only); with 4 the redundant reading is the check: its misfit ``rho_4 = q.h`` (``q`` the unit
vector orthogonal to the Jacobian's columns), zero within noise while the panel is its CAD and
the head its calibration.

**Uncertainty** (first order, GUM). A change ``delta h_i`` of the heights moves the pose by
``A delta h`` with ``A = (J^T W J)^-1 J^T W``. The heights move with

- the readings: ``delta h_i = (G_i . u_i) delta d_i``, ``G_i = dh_i/dS_i = (-g_x, -g_y, 1) +
  sigma rho K_t q_i`` (the spot's own surface slope);
- the calibration: ``delta S_i = delta E_i + d_i delta u_i`` (the per-sensor 5 x 5 blocks of the
  calibration's covariance, or the whole of it);
- the panel: an error ``delta K`` of the shape operator (mesh faceting, the drill point's position
  error along the surface, a stated form tolerance; a standard uncertainty ``u_K`` per component
  of ``delta K`` in an orthonormal basis of the tangent plane's symmetric tensors) moves
  ``h_i`` by ``sigma rho 1/2 (Tq)^T delta K (Tq)``; and the head's spin about the tool axis
  relative to the panel (``K`` turned by ``delta psi``, uniform within ``+-spin``):
  ``delta K = delta psi (W K - K W)``, ``W`` the cross matrix of ``m``.

The angle ``alpha = atan(|g|)``; its U95 the half-width that holds 95 % of the length of the
tilt, ``g``'s covariance known (:mod:`metrology.measure.magnitude`: near ``alpha = 0`` the
length's error is not normal); far from 0 the linear rule, ``K95 u``, or with the spin's uniform
share ``a`` the 95 % half-width of a normal plus a uniform on ``+-a``
(:func:`metrology.measure.magnitude.normal_uniform_u95`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.core.model import direction_basis
from metrology.core.sym3 import full as _full, inv3 as _inv3, null_vector_cols as _null_vector_cols
from metrology.core.sym3 import turned_tangent as _turned_tangent
from metrology.measure.beyond import beyond_second_order
from metrology.measure.magnitude import X_MAX, magnitude_u95, major_sd, normal_uniform_u95
from metrology.measure.normals import K95, SMALL_ANGLE_SIGMAS, HoleNormals, drill_axis
from metrology.measure.remainder import TIGHT_STEPS, surface_remainder

__all__ = ["surface_normal", "fit_surface", "surface_hole_normals", "SurfaceFit", "PanelTerms", "GN_STEPS"]

#: steps from g = 0: the first is the micro-plane (K left out), then Gauss-Newton with K; each divides the
#: error by >= 200 on panels of R >= 300 mm (sphere R 300, Table 6, noise-free: 0.23 deg after the
#: micro-plane, 1e-3 deg after one more step, 5e-6 deg after two)
GN_STEPS = 3
#: steps of the preliminary fit that only places the spots and the tilt for
#: :func:`metrology.measure.beyond.beyond_second_order` (effects themselves of second order): the
#: micro-plane and one Gauss-Newton step. Measured against GN_STEPS on 3000-hole logs: the final angle
#: moves by <= 3.6e-8 deg (Table 6 on the bundled wing, saddle, nacelle) and <= 5.6e-6 deg (a 3-sensor
#: ring on the nacelle and saddle), 1e-4 of its U95; it saves a tenth of ``measure --panel``'s time
PRELIMINARY_STEPS = 2
#: rows per call of the fit in :func:`surface_normal`: its temporaries stay in the processor's cache (as
#: :data:`metrology.measure.holes.CACHE_ROWS`; measured: 2e5 holes in one call ran at 2/3 of the rate)
SLICE_ROWS = 16384


@dataclass(frozen=True)
class SurfaceFit:
    """The local surface's pose fitted to the readings.

    Attributes
    ----------
    normal : (h, 3) float, unit, TCS, toward the head (NaN where not ok)
    g : (h, 2) float, the slopes ``(g_x, g_y)``; c : (h,) float, mm, the offset along the TCS z axis
    ok : (h,) bool, 3+ finite readings and a well-posed fit
    plane_normal : (h, 3) float, unit, TCS, toward the head: the micro-plane's (the start)
    (the rest are None unless ``fit_surface(full=True)``)
    A : (h, 3, n) float, the pose's change per unit change of each height ``h_i``
    G : (h, n, 3) float, ``dh_i / dS_i``
    q : (h, n, 3) float, mm, ``S_i - c e_z``
    w : (h, n) float, the weights used (0 for a blank)
    null : (h, n) float or None, n = 4: the unit vector orthogonal to the Jacobian's columns
    h_res : (h, n) float, mm, the heights' misfit at the solution
    Kt : (h, 3, 3) float, 1/mm, the shape operator turned onto the fitted tangent plane (``K_m``)
    """

    normal: np.ndarray
    g: np.ndarray
    c: np.ndarray
    ok: np.ndarray
    plane_normal: np.ndarray | None
    A: np.ndarray | None
    G: np.ndarray | None
    q: np.ndarray | None
    w: np.ndarray | None
    null: np.ndarray | None
    h_res: np.ndarray | None
    Kt: np.ndarray | None


def fit_surface(layout: SensorLayout, d, shape, steps: int = GN_STEPS, sigma_mm=None, full: bool = True) -> SurfaceFit:
    """Fit the local surface's pose (see the module docstring) to each hole's readings.

    Parameters
    ----------
    layout : SensorLayout, n >= 3 sensors: zero (n, 3) mm TCS, direction (n, 3) unit TCS
    d : (h, n) float, mm, readings; NaN for blanks (a hole needs 3)
    shape : (h, 3, 3) float, 1/mm, TCS, the shape operator at each hole (0: flat), tangent to the
        TCS ``xy`` plane (the head square to the panel); turned onto the fitted tangent plane; or its
        entries ``(00, 01, 11)`` as a tuple of (h,) arrays (the only ones the fit takes)
    steps : int, steps from g = 0 (the first gives the micro-plane, the rest are Gauss-Newton with ``K``)
    sigma_mm : (n,) float, mm, reading noise for the weights (default the layout's; equal when unknown)
    full : bool, also the arrays the uncertainty needs (``A``, ``G``, ``q``, ``null``, ``Kt``; else None,
        and the pass that only evaluates them at the solution is not run: the same ``normal``, ``g``, ``c``)

    Sensor-major ``(n, h)`` arrays and explicit 3 x 3 algebra: a sum over the sensors is a sum of
    contiguous rows (as :func:`metrology.measure.normals.hole_normals`).
    """
    n = layout.n
    d = np.asarray(d, float).reshape(-1, n)
    h = len(d)
    # square to the drill axis (as given): its entries in the TCS xy plane; K_m = Q K Q^T then has
    # K_m m = 0, so K_m T q = T K_m q = K_m q and (Tq)^T K_m (Tq) = q^T K_m q (no projections per step)
    if isinstance(shape, tuple):  # those entries given
        K3 = tuple(np.broadcast_to(np.asarray(k, float), (h,)) for k in shape)
        K = None
    else:
        K = np.broadcast_to(np.asarray(shape, float), (h, 3, 3))
        K3 = tuple(np.ascontiguousarray(K[:, i, j]) for i, j in ((0, 0), (0, 1), (1, 1)))  # read every step
    s = drill_axis(layout)[2]
    sg = -s
    sig = layout.noise_mm if sigma_mm is None else np.broadcast_to(np.asarray(sigma_mm, float), (n,))
    good = np.isfinite(sig) & (sig > 0)
    if not good.all():
        sig = np.where(good, sig, np.nanmean(np.where(good, sig, np.nan)) if good.any() else 1.0)
    is2 = 1.0 / (sig * sig)[:, None]  # 1 / sigma^2, (n, 1)
    dT = np.ascontiguousarray(d.T)
    valid = np.isfinite(dT)
    whole = bool(valid.all())
    if not whole:
        dT = np.where(valid, dT, 0.0)
    E, u = layout.zero, layout.direction
    x = E[:, 0, None] + dT * u[:, 0, None]  # (n, h), mm, TCS
    y = E[:, 1, None] + dT * u[:, 1, None]
    z = E[:, 2, None] + dT * u[:, 2, None]
    ok = valid.sum(0) >= 3
    u0, u1, u2 = u[:, 0, None], u[:, 1, None], u[:, 2, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        # step 0 from g = 0, c = 0 with K left out: the weighted micro-plane (rho = 1, h_i = z_i, jc = -1, Gu = u_z)
        w = is2 / (u2 * u2) * valid if not whole else is2 / (u2 * u2)  # (n, h), or (n, 1): each sensor's
        wx, wy = w * x, w * y
        i00, i01, i02, i11, i12, i22 = _inv3((wx * x).sum(0), (wx * y).sum(0), wx.sum(0), (wy * y).sum(0), wy.sum(0), w.sum(0))
        b0, b1, b2 = -(wx * z).sum(0), -(wy * z).sum(0), -(w * z).sum(0)
        gx = -(i00 * b0 + i01 * b1 + i02 * b2)
        gy = -(i01 * b0 + i11 * b1 + i12 * b2)
        c = -(i02 * b0 + i12 * b1 + i22 * b2)
        gx0, gy0 = gx, gy
        # Gauss-Newton with K; the last pass only evaluates at the solution, for the uncertainty: without
        # it (full=False) ``ok`` takes the matrix inverted for the last update. G first, the height from it:
        # ``zq - g.q + sigma rho q^T K_m q / 2 = ((G_x - g_x) x + (G_y - g_y) y + (G_z + 1) zq) / 2``; jc = -G_z
        for it in range(1, steps + 1 if full else steps):
            rho = np.sqrt(1.0 + gx * gx + gy * gy)
            mx, my, mz = -sg * gx / rho, -sg * gy / rho, sg / rho
            zq = z - c
            k00, k01, k02, k11, k12, k22 = _turned_tangent(K3, mx, my, mz, sg)  # K on the fitted tangent plane
            sc = sg * rho
            s00, s01, s02, s11, s12, s22 = sc * k00, sc * k01, sc * k02, sc * k11, sc * k12, sc * k22
            Gx = s00 * x + s01 * y + s02 * zq - gx  # (-g_x, -g_y, 1) + sigma rho K_m q
            Gy = s01 * x + s11 * y + s12 * zq - gy
            Gz = s02 * x + s12 * y + s22 * zq + 1.0
            hres = 0.5 * (x * (Gx - gx) + y * (Gy - gy) + zq * (Gz + 1.0))
            Gu = Gx * u0 + Gy * u1 + Gz * u2
            w = is2 / (Gu * Gu)
            if not whole:
                w = np.where(valid, w, 0.0)
            wx, wy, wz = w * x, w * y, w * Gz
            i00, i01, i02, i11, i12, i22 = _inv3((wx * x).sum(0), (wx * y).sum(0), (wz * x).sum(0), (wy * y).sum(0), (wz * y).sum(0),
                                                 (wz * Gz).sum(0))
            if it == steps:
                break
            b0, b1, b2 = -(wx * hres).sum(0), -(wy * hres).sum(0), -(wz * hres).sum(0)
            gx = gx - (i00 * b0 + i01 * b1 + i02 * b2)
            gy = gy - (i01 * b0 + i11 * b1 + i12 * b2)
            c = c - (i02 * b0 + i12 * b1 + i22 * b2)
    if steps == 0:
        rho = np.ones(h)
        mx, my, mz = np.zeros(h), np.zeros(h), np.full(h, sg)
        zq, hres, Gz = z, z, np.ones_like(x)
        wz = w = np.broadcast_to(w, x.shape)  # every hole's weights; w G_z = w
    ok = ok & np.isfinite(i00) & np.isfinite(gx) & np.isfinite(gy)
    rho = np.sqrt(1.0 + gx * gx + gy * gy)
    f = sg / rho
    normal = np.array([-gx * f, -gy * f, f]).T  # (h, 3), a view of (3, h)
    normal[~ok] = np.nan
    g = np.array([gx, gy]).T  # (h, 2), a view of (2, h)
    if not full:
        return SurfaceFit(normal, g, c, ok, None, None, None, None, None, None, None, None)
    A = np.empty((3, n, h))  # A = M^-1 J^T W, J = (-x, -y, jc), jc = -G_z: J^T W = -(w x, w y, w G_z)
    for r, (a0, a1, a2) in enumerate(((i00, i01, i02), (i01, i11, i12), (i02, i12, i22))):
        np.multiply(wx, -a0, out=A[r])
        A[r] -= wy * a1
        A[r] -= wz * a2
    A, jc = A.transpose(2, 0, 1), -Gz  # (h, 3, n), a view
    G = np.stack([Gx, Gy, Gz]).transpose(2, 1, 0) if steps > 0 else None  # views of (3, n, h)
    q = np.stack([x, y, zq]).transpose(2, 1, 0)
    null = _null_vector_cols(x, y, jc) if n == 4 else None  # the columns' signs: det(-a, -b, c) = det(a, b, c)
    if steps > 0:
        Kt = np.array([[k00, k01, k02], [k01, k11, k12], [k02, k12, k22]]).transpose(2, 0, 1)  # K_m = T K_m T, (h, 3, 3)
        f = sg / np.sqrt(1.0 + gx0 * gx0 + gy0 * gy0)
        plane = np.array([-gx0 * f, -gy0 * f, f]).T
    else:  # the micro-plane: K projected onto it, T K T
        if K is None:
            K = _full((K3[0], K3[1], np.zeros(h), K3[2], np.zeros(h), np.zeros(h)))
        m = np.stack([mx, my, mz], axis=1)
        Km = np.einsum("hij,hj->hi", K, m)
        mKm = (m * Km).sum(1)
        Kt = (K - m[:, :, None] * Km[:, None, :] - Km[:, :, None] * m[:, None, :]
              + mKm[:, None, None] * m[:, :, None] * m[:, None, :])
        plane = normal.copy()
    return SurfaceFit(normal, g, c, ok, plane, A, G, q, w.T, null, hres.T, Kt)


def surface_normal(layout, d, shape):
    """The panel's outward normal at each hole with its local surface known.

    Parameters
    ----------
    layout : SensorLayout (the cell's calibrated one): zero (n, 3) mm TCS, direction (n, 3) unit TCS
    d : (h, n) float, mm, readings; NaN for blanks
    shape : (h, 3, 3) float, 1/mm, TCS: the CAD surface's shape operator at the hole,
        ``k1 e1 e1^T + k2 e2 e2^T`` (``e1, e2`` the unit principal directions) as it is for the head
        square to the surface (``e1, e2`` in the TCS ``xy`` plane; the fit turns it onto the tilted one);
        curvature positive where the surface bends away from the head (a sphere drilled from
        outside: +1/R; a barrel drilled from inside: -1/R)

    Returns
    -------
    normal : (h, 3) float, unit, TCS, pointing from the surface toward the head (NaN where not ok)
    ok : (h,) bool, 3+ readings and a well-posed fit

    The cell turns the drill onto ``-normal``. This is the function a cell's controller calls per
    hole (one hole or a batch: the same arrays).
    """
    d = np.asarray(d, float)
    single = d.ndim == 1
    d = d.reshape(-1, layout.n)
    shape = np.asarray(shape, float).reshape(-1, 3, 3)
    if len(d) <= SLICE_ROWS:
        fit = fit_surface(layout, d, shape, full=False)
        if single:
            return fit.normal[0], bool(fit.ok[0])
        return fit.normal, fit.ok
    normal, ok = np.empty((len(d), 3)), np.empty(len(d), bool)
    one = len(shape) == 1
    for i in range(0, len(d), SLICE_ROWS):
        fit = fit_surface(layout, d[i:i + SLICE_ROWS], shape if one else shape[i:i + SLICE_ROWS], full=False)
        normal[i:i + SLICE_ROWS], ok[i:i + SLICE_ROWS] = fit.normal, fit.ok
    return normal, ok


@dataclass(frozen=True)
class PanelTerms:
    """What the panel adds to the budget, per hole.

    Attributes
    ----------
    u_shape : (h,) float, 1/mm, standard uncertainty of each component of the shape operator
        (mesh fit, position error along the surface, form tolerance; combined)
    spin : float or (h,) float, rad, the head's spin about the tool axis relative to the panel is
        within ``+-spin`` (uniform); 0 where the robot's commanded pose gives it
    """

    u_shape: np.ndarray
    spin: float | np.ndarray = 0.0


def _tangent_basis(mx, my, mz):
    """Two unit vectors spanning the plane square to the unit ``m``, by components: ``(t1, t2)``, each a
    tuple of three (h,) arrays (``mx, my, mz`` (h,) arrays)."""
    use_x = np.abs(mx) < 0.9  # the reference e_x, else e_y
    rm = np.where(use_x, mx, my)  # ref . m
    ax, ay, az = use_x - rm * mx, ~use_x - rm * my, -rm * mz
    f = 1.0 / np.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax * f, ay * f, az * f
    return (ax, ay, az), (my * az - mz * ay, mz * ax - mx * az, mx * ay - my * ax)  # m x t1


def _shape_basis(fit, g2, axis):
    """The heights' change ``(n, N)`` (sensor-major) per unit change of each of the three components
    of the shape operator in an orthonormal basis of the tangent plane's symmetric tensors (``t1 t1``,
    ``t2 t2``, ``(t1 t2 + t2 t1) / sqrt 2``), ``sigma rho 1/2 (Tq)^T delta K (Tq)``: a list of 3."""
    ok = fit.ok
    m = fit.normal
    t1, t2 = _tangent_basis(*(np.where(ok, m[:, i], e) for i, e in enumerate((0.0, 0.0, 1.0))))
    sc = -axis[2] * np.sqrt(1.0 + g2)  # sigma rho
    qx, qy, qz = fit.q.transpose(2, 1, 0)  # (n, N) each, mm
    a1 = qx * t1[0] + qy * t1[1] + qz * t1[2]  # (n, N), mm
    a2 = qx * t2[0] + qy * t2[1] + qz * t2[2]
    h = 0.5 * sc
    return [h * a1 * a1, h * a2 * a2, (sc / np.sqrt(2.0)) * a1 * a2]


def surface_hole_normals(layout: SensorLayout, d, shape, terms: PanelTerms | None = None,
                         covariance=None, sigma_mm=None, beyond=None):
    """Normals, angles and uncertainties of holes (every reading present) with the surface known.

    Parameters
    ----------
    layout : SensorLayout, n >= 3; d : (N, n) float, mm, finite readings
    shape : (N, 3, 3) float, 1/mm, TCS (see :func:`surface_normal`)
    terms : PanelTerms or None (the panel's own uncertainty; None: the shape is exact)
    covariance, sigma_mm : as :func:`metrology.measure.normals.hole_normals`
    beyond : None or :func:`metrology.measure.beyond.beyond_second_order`'s ``terms`` (``extra["turn"]`` its turn)

    Returns
    -------
    (HoleNormals, extra) : ``HoleNormals.normal`` along the drill axis (as the micro-plane's);
        ``twist`` zeros (the panel's shape is known: its uncertainty is in ``residual_sd``);
        ``curvature_bound`` the panel's share of ``u_angle`` (rad). ``extra`` a dict of (N,) arrays:
        ``correction`` rad (the corrected normal's angle to the micro-plane's), ``panel_misfit``
        1/mm (n = 4: the shape change along the direction the redundant reading sees, its size as
        the largest eigenvalue; NaN otherwise), ``panel_misfit_z`` (that over its standard
        uncertainty from noise, calibration and the panel's terms)
    """
    n = layout.n
    d = np.asarray(d, float).reshape(-1, n)
    N = len(d)
    Y = np.broadcast_to(np.eye(3), (N, 3, 3))  # the CAD beyond second order, the head's spin: metrology.measure.beyond
    if beyond is not None:
        fit0 = fit_surface(layout, d, shape, steps=PRELIMINARY_STEPS, sigma_mm=sigma_mm, full=False)
        d, shape, Y = beyond_second_order(layout, d, shape, beyond, fit0,  # (a tight radius: once more from a fit)
                                          lambda dd, kk: fit_surface(layout, dd, kk, TIGHT_STEPS, sigma_mm, full=False))
    fit = fit_surface(layout, d, shape, GN_STEPS if beyond is None or beyond.higher.shape[1] <= 9 else TIGHT_STEPS, sigma_mm)
    cov = layout.covariance if covariance is None else np.asarray(covariance, float)
    sigma = layout.noise_mm if sigma_mm is None else np.broadcast_to(np.asarray(sigma_mm, float), (n,))
    sigma = np.where(np.isfinite(sigma), sigma, 0.0)
    axis = drill_axis(layout)
    g = fit.g
    gx, gy = g[:, 0], g[:, 1]
    g2 = gx * gx + gy * gy
    gn = np.sqrt(g2)
    angle = np.arctan(gn)
    normal = -fit.normal  # along the drill axis
    # sensor-major (n, N) arrays (the fit's own layout: each sum over the sensors a sum of contiguous
    # rows) and the 2 x 2 covariances by their entries (00, 01, 11), (N,) each
    A0, A1 = fit.A[:, 0, :].T, fit.A[:, 1, :].T  # (n, N): the tilt's change per unit change of each height
    Ag = fit.A[:, :2, :]  # (N, 2, n)
    Gx, Gy, Gz = fit.G.transpose(2, 1, 0)  # (n, N)
    u = layout.direction
    # reading noise
    Gu = Gx * u[:, 0, None] + Gy * u[:, 1, None] + Gz * u[:, 2, None]  # (n, N)
    qn = (Gu * sigma[:, None]) ** 2

    def cov2(qq):  # sum_n A_i qq A_j
        a0 = A0 * qq
        return [(a0 * A0).sum(0), (a0 * A1).sum(0), (A1 * qq * A1).sum(0)]

    C_noise = cov2(qn)
    # calibration
    C_cal = [np.zeros(N)] * 3
    q_cal = np.zeros((n, N))
    if cov is not None:
        e = direction_basis(u)  # (n, 2, 3)
        r = [Gx, Gy, Gz] + [d.T * (Gx * e[:, k, 0, None] + Gy * e[:, k, 1, None] + Gz * e[:, k, 2, None]) for k in range(2)]
        blocks = np.stack([cov[5 * i:5 * i + 5, 5 * i:5 * i + 5] for i in range(n)])  # (n, 5, 5)
        off = cov.copy()
        for i in range(n):
            off[5 * i:5 * i + 5, 5 * i:5 * i + 5] = 0.0
        q_cal = sum(r[k] * sum(blocks[:, k, l, None] * r[l] for l in range(5)) for k in range(5))  # (n, N)
        if not np.any(off):
            C_cal = cov2(q_cal)
        else:  # the whole covariance
            rows = np.stack(r, axis=-1).transpose(1, 0, 2)  # (N, n, 5)
            Sx = (rows * Ag[:, 0, :, None]).reshape(N, -1)
            Sy = (rows * Ag[:, 1, :, None]).reshape(N, -1)
            Sg = np.stack([Sx, Sy], axis=1)  # (N, 2, 5n)
            Cc = np.einsum("hik,kl,hjl->hij", Sg, cov, Sg)
            C_cal = [Cc[:, 0, 0], Cc[:, 0, 1], Cc[:, 1, 1]]
    # the panel: delta K in an orthonormal basis of the tangent plane's symmetric tensors, and the spin
    C_pan = [np.zeros(N)] * 3
    dh_basis = dh_spin = v_spin = None
    if terms is not None:
        m = fit.normal
        dh_basis = _shape_basis(fit, g2, axis)  # (n, N) each
        uK = np.asarray(terms.u_shape, float).reshape(-1)
        uK2 = np.broadcast_to(uK, (N,)) ** 2
        for dh in dh_basis:
            v0, v1 = (A0 * dh).sum(0), (A1 * dh).sum(0)
            C_pan = [C_pan[0] + v0 * v0 * uK2, C_pan[1] + v0 * v1 * uK2, C_pan[2] + v1 * v1 * uK2]
        spin = np.broadcast_to(np.asarray(terms.spin, float), (N,))
        if np.any(spin > 0):
            sc = (-axis[2] * np.sqrt(1.0 + g2))[:, None]  # sigma rho
            W = np.zeros((N, 3, 3))
            W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -m[:, 2], m[:, 1], -m[:, 0]
            W[:, 1, 0], W[:, 2, 0], W[:, 2, 1] = m[:, 2], -m[:, 1], m[:, 0]
            dK = W @ fit.Kt - fit.Kt @ W
            dh = sc * 0.5 * np.einsum("hni,hij,hnj->hn", fit.q, dK, fit.q)
            dh_spin = dh.T  # (n, N)
            v = np.einsum("hin,hn->hi", Ag, dh)
            v_spin = v * spin[:, None]  # the tilt at the spin's end, +-spin
            f = spin ** 2 / 3.0
            C_pan = [C_pan[0] + v[:, 0] * v[:, 0] * f, C_pan[1] + v[:, 0] * v[:, 1] * f, C_pan[2] + v[:, 1] * v[:, 1] * f]
    rem = surface_remainder(fit, u, None if beyond is None else beyond.u_height)  # the budget's "surface model"
    C_pan = [a + b for a, b in zip(C_pan, rem.cov)]  # a panel term (in its share)
    C = [a + b + c for a, b, c in zip(C_noise, C_cal, C_pan)]
    with np.errstate(invalid="ignore", divide="ignore"):
        k = 1.0 / (gn * (1.0 + g2))
    k = np.where(np.isfinite(k), k, 0.0)
    c0, c1 = gx * k, gy * k

    def quad(Cm):
        return c0 * c0 * Cm[0] + 2.0 * c0 * c1 * Cm[1] + c1 * c1 * Cm[2]

    var_noise = quad(C_noise)
    var_pan = quad(C_pan)
    var = var_noise + quad(C_cal) + var_pan
    u_angle = np.sqrt(var)
    if v_spin is None:
        U95 = K95 * u_angle
    else:  # the spin's share is uniform, not normal: the 95 % half-width of their sum
        a_spin = np.abs(c0 * v_spin[:, 0] + c1 * v_spin[:, 1])  # rad, the angle at the spin's end
        U95 = normal_uniform_u95(np.sqrt(np.maximum(var - a_spin ** 2 / 3.0, 0.0)), a_spin)
    f = 1.0 / ((1.0 + g2) ** 2)
    Ca = np.empty((N, 2, 2))  # rad^2: the tilt's covariance in angle
    Ca[:, 0, 0], Ca[:, 1, 1] = C[0] * f, C[2] * f
    Ca[:, 0, 1] = Ca[:, 1, 0] = C[1] * f
    s2d = major_sd(Ca)  # rad: its major axis's standard deviation
    # near 0, u is the 2-D spread's major axis
    still = (angle < SMALL_ANGLE_SIGMAS * 2.0 * u_angle) & (angle < SMALL_ANGLE_SIGMAS * s2d)
    u_angle[still] = s2d[still]
    # U95: the half-width holding 95 % of the length of the tilt (metrology.measure.magnitude); the
    # linear rule beyond X_MAX major-axis standard deviations
    near = angle < X_MAX * s2d
    if np.any(near):
        with np.errstate(invalid="ignore", divide="ignore"):
            tilt = g[near] * np.where(gn[near] > 0, angle[near] / gn[near], 1.0)[:, None]  # rad, length = angle
        U95[near] = magnitude_u95(tilt, Ca[near])
    panel_share = np.sqrt(np.maximum(var_pan, 0.0))
    residual, residual_z, misfit, misfit_z = (np.full(N, np.nan) for _ in range(4))
    signature = twist = residual_sd = sd = None
    if n == 4:
        qv = fit.null.T  # (n, N)
        residual = (qv * fit.h_res.T).sum(0)
        sig_k = qv * Gu
        sd = np.sqrt(((sig_k * sigma[:, None]) ** 2).sum(0))
        with np.errstate(invalid="ignore", divide="ignore"):
            residual_z = residual / sd
        var_pan_rho = np.zeros(N)
        # the shape change the redundant reading sees: rho = sum_b (q . dh_b) x_b
        basis = dh_basis if dh_basis is not None else _shape_basis(fit, g2, axis)
        s_b = [(qv * b).sum(0) for b in basis]  # d rho / d x_b
        sb2 = s_b[0] * s_b[0] + s_b[1] * s_b[1] + s_b[2] * s_b[2]
        if terms is not None:
            var_pan_rho = sb2 * np.broadcast_to(np.asarray(terms.u_shape, float), (N,)) ** 2
            if dh_spin is not None:  # the spin turns the shape's twist: the redundant reading sees it
                var_pan_rho = var_pan_rho + (qv * dh_spin).sum(0) ** 2 * spin ** 2 / 3.0
        residual_sd = np.sqrt(sd * sd + (qv * qv * q_cal).sum(0) + var_pan_rho + rem.var_rho)
        signature = sig_k.T
        twist = np.zeros(N)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = residual / sb2
            # the least-norm shape change giving rho; its size: the largest |eigenvalue| of
            # x1 t1t1 + x2 t2t2 + x3 (t1t2 + t2t1)/sqrt2
            a, b, cc = s_b[0] * f, s_b[1] * f, s_b[2] * f / np.sqrt(2.0)
            misfit = np.abs(0.5 * (a + b)) + np.sqrt(0.25 * (a - b) ** 2 + cc * cc)
            misfit_z = residual / residual_sd
    elif n > 4:
        res = fit.h_res
        residual = np.sqrt((res * res).sum(1) / n)
        v = ((Gu * sigma[:, None]) ** 2).T
        with np.errstate(invalid="ignore", divide="ignore"):
            residual_z = np.sqrt((res * res / v).sum(1) / (n - 3))
    with np.errstate(invalid="ignore"):
        nm, pm = fit.normal, fit.plane_normal
        correction = np.arccos(np.clip(nm[:, 0] * pm[:, 0] + nm[:, 1] * pm[:, 1] + nm[:, 2] * pm[:, 2], -1.0, 1.0))
    bad = ~fit.ok
    for arr in (angle, u_angle, U95, correction):
        arr[bad] = np.nan
    normal[bad] = np.nan
    hn = HoleNormals(normal, angle, u_angle, U95, np.sqrt(var_noise), residual, residual_z,
                     None if signature is None else np.ascontiguousarray(signature), panel_share, twist,
                     residual_sd, sd)
    return hn, {"correction": correction, "panel_misfit": misfit, "panel_misfit_z": misfit_z, "turn": Y, "remainder": rem}

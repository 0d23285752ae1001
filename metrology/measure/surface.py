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
slope; what is left out of it is of order ``|K| |m.q|``), vectorised over holes. Both are one
estimator, :func:`metrology.measure.estimator.fit_tilt` (its weights and why: there): on a flat
panel this fit, and its budget, are the micro-plane's to the last bit.

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

from dataclasses import dataclass, replace

import numpy as np

from metrology.core.layout import SensorLayout
from metrology.core.sym2 import eig2
from metrology.measure.beyond import beyond_second_order
from metrology.measure.budget import PANEL_SHAPE, READING_NOISE, SPIN, SPIN_READ, SURFACE_MODEL, Budget, Source, combine
from metrology.measure.estimator import SurfaceFit, drill_axis, fit_tilt
from metrology.measure.normals import HoleNormals
from metrology.measure.panel_terms import PanelTerms, free_spin, panel_sources, shape_basis
from metrology.measure.terms import reading_sigma, reading_sources, redundancy
from metrology.measure.remainder import TIGHT_STEPS, surface_remainder

__all__ = ["surface_normal", "fit_surface", "surface_hole_normals", "SurfaceFit", "PanelTerms", "PanelFit", "GN_STEPS"]

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
#: :data:`metrology.measure.measured.CACHE_ROWS`; measured: 2e5 holes in one call ran at 2/3 of the rate)
SLICE_ROWS = 16384


def fit_surface(layout: SensorLayout, d, shape, steps: int = GN_STEPS, sigma_mm=None, full: bool = True) -> SurfaceFit:
    """Fit the local surface's pose (see the module docstring) to each hole's readings:
    :func:`metrology.measure.estimator.fit_tilt` with the shape, the estimator of the micro-plane too.

    Parameters
    ----------
    layout : SensorLayout, n >= 3 sensors: zero (n, 3) mm TCS, direction (n, 3) unit TCS
    d : (h, n) float, mm, readings; NaN for blanks (a hole needs 3)
    shape : (h, 3, 3) float, 1/mm, TCS, the shape operator at each hole (0: flat), tangent to the
        TCS ``xy`` plane (the head square to the panel); turned onto the fitted tangent plane; or its
        entries ``(00, 01, 11)`` as a tuple of (h,) arrays (the only ones the fit takes)
    steps : int >= 1, the first gives the micro-plane, the rest are Gauss-Newton with ``K``
    sigma_mm : (n,) float, mm, the reading noise the weights take (default the layout's)
    full : bool, also the arrays the uncertainty needs (``A``, ``G``, ``q``, ``null``, ``Kt``; else None,
        and the pass that only evaluates them at the solution is not run: the same ``normal``, ``g``, ``c``)
    """
    return fit_tilt(layout, d, shape, steps, sigma_mm, full)


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
class PanelFit:
    """What the panel's fit gives per hole beside its normals (:func:`surface_hole_normals`).

    Attributes
    ----------
    correction : (h,) float, rad, the corrected normal's angle to the micro-plane's
    panel_misfit : (h,) float, 1/mm, n = 4: the shape change along the direction the redundant reading
        sees, its size the largest eigenvalue (NaN otherwise)
    panel_misfit_z : (h,) float, that over its standard uncertainty (noise, calibration, the panel's terms;
        where the spin is not known: what is beyond every spin's)
    turn : (h, 3, 3) float, the turn about the axis applied (:mod:`metrology.measure.beyond`)
    spot_turn : (h,) float, rad, the most the fitted surface has turned at a spot from the hole's normal
    incidence : (h,) float, rad, the largest angle a beam meets the fitted surface at
        (both :func:`metrology.measure.remainder.spot_geometry`: rule 1b of :mod:`metrology.measure.rules`)
    """

    correction: np.ndarray
    panel_misfit: np.ndarray
    panel_misfit_z: np.ndarray
    turn: np.ndarray
    spot_turn: np.ndarray
    incidence: np.ndarray

    @staticmethod
    def blank(h: int) -> "PanelFit":
        """``h`` holes of NaN (to fill)."""
        return PanelFit(np.full(h, np.nan), np.full(h, np.nan), np.full(h, np.nan), np.full((h, 3, 3), np.nan),
                        np.full(h, np.nan), np.full(h, np.nan))

    @staticmethod
    def concat(parts) -> "PanelFit":
        return PanelFit(*(np.concatenate([getattr(p, f) for p in parts]) for f in PanelFit.__dataclass_fields__))

    def rows(self, r) -> "PanelFit":
        return PanelFit(*(getattr(self, f)[r] for f in PanelFit.__dataclass_fields__))

    def put(self, r, other: "PanelFit") -> None:
        """Write ``other``'s holes into the rows ``r``."""
        for f in PanelFit.__dataclass_fields__:
            getattr(self, f)[r] = getattr(other, f)


def surface_hole_normals(layout: SensorLayout, d, shape, terms: PanelTerms | None = None,
                         covariance=None, sigma_mm=None, beyond=None):
    """Normals, angles and uncertainties of holes (every reading present) with the surface known.

    Parameters
    ----------
    layout : SensorLayout, n >= 3; d : (N, n) float, mm, finite readings
    shape : (N, 3, 3) float, 1/mm, TCS (see :func:`surface_normal`)
    terms : PanelTerms or None (the panel's own uncertainty; None: the shape is exact)
    covariance, sigma_mm : as :func:`metrology.measure.normals.hole_normals`
    beyond : None or :func:`metrology.measure.beyond.beyond_second_order`'s ``terms`` (``PanelFit.turn`` its turn)

    Returns
    -------
    (HoleNormals, PanelFit) : ``HoleNormals.normal`` along the drill axis (as the micro-plane's);
        ``twist`` zeros (the panel's shape is known: its uncertainty is in ``residual_sd``);
        ``curvature_bound`` the panel's share of ``u_angle`` (rad); ``budget`` its sources (reading noise,
        calibration, panel shape, spin)
    """
    n = layout.n
    d = np.asarray(d, float).reshape(-1, n)
    N = len(d)
    Y = np.broadcast_to(np.eye(3), (N, 3, 3))  # the CAD beyond second order, the head's spin: metrology.measure.beyond
    free = terms is not None and terms.free
    if free:  # the spin unknown: the isotropic part fitted (the same at every spin), the rest a bound
        k00, k01, k11 = (np.broadcast_to(np.asarray(k, float), (N,)) for k in
                         (shape if isinstance(shape, tuple) else (shape[:, 0, 0], shape[:, 0, 1], shape[:, 1, 1])))
        mean = 0.5 * (k00 + k11)
        dev = np.sqrt(0.25 * (k00 - k11) ** 2 + k01 * k01)
        shape, beyond = (mean, np.zeros(N), mean), None
    cov = layout.covariance if covariance is None else np.asarray(covariance, float)
    if beyond is not None:
        fit0 = fit_surface(layout, d, shape, PRELIMINARY_STEPS, sigma_mm, full=False)
        d, shape, Y = beyond_second_order(layout, d, shape, beyond, fit0,  # (a tight radius: once more from a fit)
                                          lambda dd, kk: fit_surface(layout, dd, kk, TIGHT_STEPS, sigma_mm, full=False))
    fit = fit_surface(layout, d, shape, GN_STEPS if beyond is None or beyond.higher.shape[1] <= 9 else TIGHT_STEPS, sigma_mm)
    sigma = reading_sigma(layout, sigma_mm)
    axis = drill_axis(layout)
    g = fit.g
    gx, gy = g[:, 0], g[:, 1]
    g2 = gx * gx + gy * gy
    normal = -fit.normal  # along the drill axis
    # sensor-major (n, N) arrays (the fit's own layout: each sum over the sensors a sum of contiguous rows); the
    # reading noise and calibration as the micro-plane's (one code: a flat panel gives its budget exactly)
    A0, A1, Gu, noise, cal, q_cal = reading_sources(layout, fit, np.ascontiguousarray(d.T), cov, sigma)
    u = layout.direction
    basis = shape_basis(fit, g2, axis) if terms is not None or n == 4 else None  # one for every use below
    shape_src, spin_src, read_src, rho_var = panel_sources(fit, g2, axis, terms, A0, A1, basis)
    rho_bound = None
    if free:
        spin_src, rho_bound = free_spin(fit, g2, axis, dev, A0, A1, basis)
    rem = surface_remainder(fit, u, None if beyond is None else beyond.u_height)  # truncation, faceting, position
    budget = Budget(g.copy(), (noise, cal, shape_src, spin_src, read_src, Source(SURFACE_MODEL, rem.cov)))
    un = combine(budget)
    budget = replace(budget, combined=un)  # kept: the spin's share is read from it again (metrology.measure.spin)
    bad = ~fit.ok
    angle, u_angle, U95 = un.angle.copy(), un.u.copy(), un.U95.copy()  # their not-ok rows blanked below, not un's
    panel_share = np.sqrt(un.of(PANEL_SHAPE) ** 2 + un.of(SPIN) ** 2 + un.of(SPIN_READ) ** 2
                          + un.of(SURFACE_MODEL) ** 2)
    misfit = np.full(N, np.nan)
    misfit_z = np.full(N, np.nan)
    twist = None
    if n == 4:
        qv = fit.null.T  # (n, N)
        s_b = [(qv * b).sum(0) for b in basis]  # d rho / d x_b: the shape change the redundant reading sees
        sb2 = s_b[0] * s_b[0] + s_b[1] * s_b[1] + s_b[2] * s_b[2]
        extra = 0.0
        if terms is not None:
            extra = extra + sb2 * np.broadcast_to(np.asarray(terms.u_shape, float), (N,)) ** 2 + rho_var
        red = redundancy(qv, fit.h_res.T, Gu, sigma, q_cal, extra)
        twist = np.zeros(N)
        with np.errstate(invalid="ignore", divide="ignore"):
            f = red.residual / sb2
            # the least-norm shape change giving rho; its size: the largest |eigenvalue| of
            # x1 t1t1 + x2 t2t2 + x3 (t1t2 + t2t1)/sqrt2
            a, b, cc = s_b[0] * f, s_b[1] * f, s_b[2] * f / np.sqrt(2.0)
            l1, l2 = eig2(a, cc, b)
            misfit = np.maximum(np.abs(l1), np.abs(l2))
            misfit_z = red.residual / red.sd
            if rho_bound is not None:  # the spin not known: the misfit beyond what any spin gives
                misfit_z = np.sign(red.residual) * np.maximum(np.abs(red.residual) - rho_bound, 0.0) / red.sd
    else:
        red = redundancy(None, fit.h_res.T, Gu, sigma, q_cal)
    with np.errstate(invalid="ignore"):
        nm, pm = fit.normal, fit.plane_normal
        correction = np.arccos(np.clip(nm[:, 0] * pm[:, 0] + nm[:, 1] * pm[:, 1] + nm[:, 2] * pm[:, 2], -1.0, 1.0))
    for arr in (angle, u_angle, U95, correction):
        arr[bad] = np.nan
    normal[bad] = np.nan
    hn = HoleNormals(normal, angle, u_angle, U95, un.of(READING_NOISE), red.residual, red.residual_z, red.signature,
                     panel_share, twist, red.sd, red.noise_sd, budget,
                     np.zeros(N) if rho_bound is None else rho_bound)
    return hn, PanelFit(correction, misfit, misfit_z, np.ascontiguousarray(Y), rem.turn, rem.incidence)

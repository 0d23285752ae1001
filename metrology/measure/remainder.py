"""What the local surface model leaves over the head's footprint, per hole: a term of U95 (the budget's
source "surface model") and the geometry that says whether the model holds at all (the footprint rule,
:data:`metrology.measure.rules.MAX_SPOT_TURN_DEG`, :data:`metrology.measure.rules.MAX_INCIDENCE_DEG`).

**The term.** :func:`metrology.measure.surface.fit_surface` fits the spots to the panel's second-order
surface; :mod:`metrology.measure.beyond` moves the readings by the CAD's height beyond it (the quartic, and
where the footprint is large against the radius the degrees 5 to 8 fitted over the footprint's disc:
:mod:`metrology.panel.footprint`). What no term carries, ``u_height`` (mm, per hole: the RMS residual of
that fit over the disc, the truncation beyond degree 8 and the vertices' own error; the mesh's faceting
where the shape came from ray-cast heights is in ``u_shape``), is taken as an independent height error of
each spot along the normal, standard uncertainty ``u_height``. The fit's heights ``h_i`` are ``rho`` times
the height along ``m`` (``rho = sqrt(1 + |g|^2)``), so the tilt moves by ``A delta h``:

    C_g = (rho u_height)^2 sum_i A_i A_i^T        (2 x 2, the tilts' rows of A)

and with 4 sensors the redundant reading's misfit by ``(rho u_height)^2 sum_i q_i^2``. Zero where the
footprint does not need it (:data:`metrology.panel.footprint.NEEDED_MM`).

**The geometry** (:func:`spot_geometry`): at each spot the surface's normal from the fitted second-order
surface, ``G_i = (-g_x, -g_y, 1) + sigma rho K_m q_i``: its tangent part ``v = sigma rho K_m q_i`` over ``rho``
is the sine of the surface's turn from the hole's normal (exact on a circle: ``r / R``); the spot's normal is
``G0^ cos + v^ sin``. Returned: the largest turn over the spots and the largest angle of incidence of a beam
on the surface (between ``-u_i`` and the spot's normal).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metrology.measure.terms import tilt_cov

__all__ = ["Remainder", "surface_remainder", "remainder_covariance", "spot_geometry", "TIGHT_STEPS"]

#: steps of :func:`metrology.measure.surface.fit_surface` where the footprint is large against the radius (the CAD's
#: terms beyond the quartic in use): its Gauss-Newton step leaves ~``|K| |m.q| ~ (k r)^2 / 2`` of the error (0.12 at R 50
#: under a 25 mm footprint, against <= 1/200 at R >= 300): 3 steps left 0.003 deg rms (noise-free, Table 2 head, R 50),
#: 6 leave 5e-5 deg (benchmarks/results/tight_radii.md)
TIGHT_STEPS = 6


@dataclass(frozen=True)
class Remainder:
    """What the surface model leaves, per hole (:func:`surface_remainder`).

    Attributes
    ----------
    cov : (N, 3) float, the 2 x 2 covariance of the slopes ``g`` by its entries ``(00, 01, 11)`` (the Budget
        source "surface model"; zeros where no ``u_height``)
    var_rho : (N,) float or 0.0, mm^2, the redundant reading's misfit's variance from it
    turn : (N,) float, rad, the largest turn of the surface from the hole's normal at a spot
    incidence : (N,) float, rad, the largest angle of incidence of a beam on the surface
    """

    cov: np.ndarray
    var_rho: np.ndarray | float
    turn: np.ndarray
    incidence: np.ndarray


def surface_remainder(fit, direction, u_height=None) -> Remainder:
    """The remainder's covariance (:func:`remainder_covariance`, where ``u_height`` (N,) mm is given) and
    the spots' geometry (:func:`spot_geometry`) of a full :class:`metrology.measure.surface.SurfaceFit`."""
    N = len(fit.g)
    if u_height is None:
        cov, var_rho = np.zeros((N, 3)), 0.0
    else:
        cov, var_rho = remainder_covariance(fit, u_height)
    return Remainder(cov, var_rho, *spot_geometry(fit, direction))


def remainder_covariance(fit, u_height):
    """The surface model's remainder as a tilt covariance.

    Parameters
    ----------
    fit : metrology.measure.surface.SurfaceFit, ``full=True`` (``A (N, 3, n)``, ``g (N, 2)``, ``null``)
    u_height : (N,) float, mm, the height no term carries, per hole

    Returns
    -------
    cov : (N, 3) float, the 2 x 2 covariance of the slopes ``g`` by its entries ``(00, 01, 11)``
    var_rho : (N,) float, mm^2, the redundant reading's misfit's variance from it (zeros with 3 sensors)
    """
    g = fit.g
    v = (1.0 + g[:, 0] ** 2 + g[:, 1] ** 2) * np.asarray(u_height, float) ** 2  # (rho u)^2, (N,)
    A0, A1 = fit.A[:, 0, :].T, fit.A[:, 1, :].T  # (n, N)
    cov = tilt_cov(A0, A1, np.broadcast_to(v, A0.shape))  # independent heights, each of variance v
    var_rho = v * (fit.null * fit.null).sum(1) if fit.null is not None else np.zeros(len(v))
    return cov, var_rho


def spot_geometry(fit, direction):
    """``(turn, incidence)``: (N,) float, rad, the largest turn of the surface from the hole's normal at a
    spot, and the largest angle of incidence of a beam on it (module docstring).

    ``fit`` a full :class:`metrology.measure.surface.SurfaceFit` (``G (N, n, 3)``, ``g``), ``direction (n, 3)``
    unit TCS the beams. Sensor-major ``(n, N)`` arrays, one per component (``G``'s own memory order), and the
    largest turn and incidence taken of the sine and the cosine before their inverse (both monotonic): one
    ``arcsin`` and one ``arccos`` per hole, not per spot."""
    Gx, Gy, Gz = fit.G.transpose(2, 1, 0)  # (n, N) each
    g = fit.g
    gx, gy = g[:, 0], g[:, 1]
    rho = np.sqrt(1.0 + gx ** 2 + gy ** 2)
    vx, vy, vz = Gx - (-gx), Gy - (-gy), Gz - 1.0  # the tangent part, G - (-g_x, -g_y, 1)
    vn = np.sqrt(vx * vx + vy * vy + vz * vz)  # (n, N)
    sin = np.clip(vn / rho, 0.0, 1.0)
    cos = np.sqrt(1.0 - sin * sin)
    u = np.asarray(direction, float)
    cos_inc = None
    with np.errstate(invalid="ignore", divide="ignore"):
        for k, (vk, g0) in enumerate(((vx, -gx), (vy, -gy), (vz, 1.0))):
            hat = np.where(vn > 0, vk / vn, 0.0)
            nk = (g0 / rho) * cos + hat * sin  # the spot's unit normal, component k
            term = nk * u[:, k, None]
            cos_inc = term if cos_inc is None else cos_inc + term
    cos_inc = np.abs(cos_inc)
    return np.arcsin(sin.max(0)), np.arccos(np.clip(cos_inc, 0.0, 1.0).min(0))

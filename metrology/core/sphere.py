"""The micro-sphere: an algebraic sphere through the laser spots, and the normal it gives.

The companion of :func:`metrology.core.normals.micro_plane_normal` on doubly curved panels."""

from __future__ import annotations

import numpy as np
from metrology.core.normals import micro_plane_normal, projection_points


#: the micro-sphere's prior on curvature: 1 sigma of the curvature is 1 / this (mm). It
#: decides, given the reading noise, how much evidence a curvature needs before it is
#: believed; it picks the plane where the spots do not determine the curvature at all
SPHERE_PRIOR_RADIUS_MM = 100.0


#: tie-break weight of the prior row when the noise is 0 (scaled units): it only decides
#: between the members of a pencil the spots cannot tell apart (concyclic spots: the plane)
#: and moves a determined sphere by ~1e-12 relative, far below 1e-6 deg
SPHERE_TIE_BREAK = 1e-12


#: a root of the axis/sphere quadratic is taken as the plane root when |A| is below this
#: (unitless, scaled coordinates)
SPHERE_FLAT_A = 1e-12


def fit_algebraic_sphere(S, noise_mm=0.0, prior_radius_mm=SPHERE_PRIOR_RADIUS_MM):
    """The algebraic sphere ``A |x|^2 + b . x + c = 0`` through (or nearest) the spots, MAP.

    Points are centred and scaled by their RMS radius ``s``; the coefficient vector
    ``u = (A, b, c)`` minimises ``|M u|^2 + lambda A^2`` with ``|u| = 1`` (the smallest
    eigenvector). Near the spots ``|b| ~ 1``, a row of ``M u`` is the spot's height off the
    sphere over ``s`` and ``A = kappa s / 2``, so with ``lambda = 4 sigma^2 / (kappa0^2 s^4)``
    this is the maximum a posteriori sphere for reading noise ``sigma`` and a prior
    ``kappa ~ N(0, kappa0^2)``, ``kappa0 = 1 / prior_radius_mm``: a curvature is believed
    only as far as the spots' geometry resolves it above the noise. With well-spread spots
    and no noise four spots give the sphere through them; where the spots do not determine
    the curvature (coplanar and concyclic: flat panel, symmetric head) the flattest member
    of the pencil, the plane, is chosen. ``A -> 0`` is a plane: nothing divides by the
    radius, so nothing blows up.

    Parameters
    ----------
    S : (p, n, 3) float, mm, any frame, n >= 4, all finite
    noise_mm : float, mm, 1 sigma of a spot along the normal; 0: the data are exact and
        the prior vanishes (only the :data:`SPHERE_TIE_BREAK` remains)
    prior_radius_mm : float, mm; inf: no prior (the exact interpolating sphere)

    Returns
    -------
    u : (p, 5) float, coefficients in scaled coordinates ``x' = (x - centre) / scale``
    centre : (p, 3) float, mm
    scale : (p,) float, mm
    """
    S = np.asarray(S, float)
    if S.ndim != 3 or S.shape[-1] != 3 or S.shape[1] < 4:
        raise ValueError(f"a sphere needs (p, n>=4, 3) points, got shape {S.shape}")
    centre = S.mean(axis=1)
    X = S - centre[:, None, :]
    scale = np.sqrt(np.mean(np.sum(X * X, axis=2), axis=1))
    scale = np.where(scale > 0, scale, 1.0)
    X = X / scale[:, None, None]
    M = np.concatenate([np.sum(X * X, axis=2, keepdims=True), X, np.ones(X.shape[:2] + (1,))], axis=2)
    sigma = float(noise_mm)
    if not (sigma >= 0 and np.isfinite(sigma)):
        raise ValueError(f"the spots' noise must be a finite number >= 0 mm, got {noise_mm}")
    kappa0 = 1.0 / float(prior_radius_mm)
    lam = 4.0 * sigma**2 / (kappa0**2 * scale**4) if kappa0 > 0 else np.zeros_like(scale)
    # the prior as one more row (SVD of the stacked matrix: no squared condition number);
    # a tiny floor breaks the tie of an exactly concyclic pencil towards the plane
    prior = np.zeros((len(S), 1, 5))
    prior[:, 0, 0] = np.sqrt(lam + SPHERE_TIE_BREAK**2)
    _, _, vt = np.linalg.svd(np.concatenate([M, prior], axis=1), full_matrices=True)
    return vt[:, -1, :], centre, scale


def micro_sphere_normal(zero, direction, d, axis=(0.0, 0.0, 1.0), origin=(0.0, 0.0, 0.0), noise_mm=0.0,
                        prior_radius_mm=SPHERE_PRIOR_RADIUS_MM):
    """Micro-sphere normal at the point where the tool axis meets the sphere through the spots.

    Parameters
    ----------
    zero : (n, 3) float, mm, TCS
    direction : (n, 3) float, unit, TCS
    d : (p, n) float, mm, readings; a pose with a NaN reading gives NaN
    axis : (3,) float, unit, TCS, the tool axis direction
    origin : (3,) float, mm, TCS, a point of the tool axis
    noise_mm, prior_radius_mm : float, mm, see :func:`fit_algebraic_sphere`

    Returns
    -------
    n : (p, 3) float, unit, TCS, oriented against the mean beam direction
    radius : (p,) float, mm, the sphere's radius; inf where it degraded to the plane
    point : (p, 3) float, mm, TCS, where the axis meets the sphere (nearest to the axis
        where it misses)
    misses : (p,) bool, the axis misses the sphere (the normal is then taken at the point
        of the sphere nearest to the axis)

    Notes
    -----
    **Four sensors** determine the sphere: with exact readings (``noise_mm = 0``) the
    normal is that of the sphere through the four spots, exact to rounding wherever the
    spots land, for any beam layout. **More than four**: the algebraic least-squares sphere
    (exact too when the spots are). **Three sensors**: a sphere through 3 points is not
    unique: a one-parameter pencil passes through them (centres on the line through the
    spots' circumcentre, normal to their plane), from the plane to the smallest sphere, and
    the spots say nothing about which. Under the zero-mean curvature prior the most likely
    member is the plane, so the micro-plane is returned (radius inf). It is exact on a
    sphere only where the tool axis meets the sphere on the line from its centre through the
    spots' circumcentre (a symmetric head square to the surface); otherwise its error is
    the micro-plane's. Other choices (the sphere of the prior's radius, or with its centre
    on the tool axis) would need the curvature, or its sign, from elsewhere: not done.
    """
    zero = np.asarray(zero, float)
    direction = np.asarray(direction, float)
    S = projection_points(zero, direction, d)
    p = S.shape[0]
    toward = -direction.mean(axis=0)
    toward /= np.linalg.norm(toward)
    axis = np.asarray(axis, float)
    origin = np.asarray(origin, float)
    n_out = np.full((p, 3), np.nan)
    rad = np.full(p, np.nan)
    pt = np.full((p, 3), np.nan)
    miss = np.zeros(p, bool)
    ok = np.all(np.isfinite(S), axis=(1, 2))
    if S.shape[1] < 4:
        n_out[ok] = micro_plane_normal(zero, direction, np.atleast_2d(d)[ok], method="lsq")
        rad[ok] = np.inf
        # the plane's axis point: through the spot centroid
        c = S[ok].mean(axis=1)
        t = np.sum((c - origin) * n_out[ok], axis=1) / (n_out[ok] @ axis)
        pt[ok] = origin + t[:, None] * axis
        return n_out, rad, pt, miss
    if not np.any(ok):
        return n_out, rad, pt, miss
    u, c, s = fit_algebraic_sphere(S[ok], noise_mm, prior_radius_mm)
    A, b, c0 = u[:, 0], u[:, 1:4], u[:, 4]
    X0 = (origin - c) / s[:, None]  # axis origin, scaled coordinates
    # A t^2 + B t + C = 0 along X0 + t a
    B = 2 * A * (X0 @ axis) + b @ axis
    C = A * np.sum(X0 * X0, axis=1) + np.sum(b * X0, axis=1) + c0
    disc = B * B - 4 * A * C
    m = disc < 0
    disc = np.where(m, 0.0, disc)
    q = -0.5 * (B + np.copysign(np.sqrt(disc), B))
    flat = np.abs(A) < SPHERE_FLAT_A
    with np.errstate(divide="ignore", invalid="ignore"):
        t_plane_like = np.where(q != 0, C / q, -C / np.where(B != 0, B, 1.0))
        t_other = np.where(flat, np.nan, q / np.where(flat, 1.0, A))
        t_tangent = -B / (2 * np.where(flat, 1.0, A))
    # of the two roots, the one nearer to the spots' centroid projected on the axis: it is
    # the one that tends to the plane's root as A -> 0 (and on a tie, that one). For a
    # sphere the size of the spot circle the two are equally near and equally wrong: such a
    # sphere is a model error (a cylinder or saddle under four spots; see the study)
    tc = np.sum(-X0 * axis, axis=1)  # axis parameter nearest the spot centroid (origin 0)
    pick_other = ~flat & (np.abs(t_other - tc) < np.abs(t_plane_like - tc) - 1e-12)
    t = np.where(pick_other, t_other, t_plane_like)
    t = np.where(m & ~flat, t_tangent, t)
    X = X0 + t[:, None] * axis
    g = 2 * A[:, None] * X + b
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    g *= np.where(np.sum(g * toward, axis=1) < 0, -1.0, 1.0)[:, None]
    n_out[ok] = g
    with np.errstate(divide="ignore", invalid="ignore"):
        r2 = np.sum(b * b, axis=1) - 4 * A * c0
        rad[ok] = np.where(flat, np.inf, np.sqrt(np.maximum(r2, 0.0)) / (2 * np.abs(A)) * s)
    pt[ok] = c + X * s[:, None]
    miss[ok] = m & ~flat
    return n_out, rad, pt, miss

"""The CAD surface over the head's whole footprint, beyond the local quartic: for ``metro measure --panel``
on radii small against the footprint (leading edges, lips, tubes).

:func:`metrology.panel.holes.panel_surfaces` gives each hole the surface's Taylor terms up to the quartic,
fitted to the mesh's vertices *near* the point. Over a footprint large against the radius that is not
enough: a cylinder's height ``R - sqrt(R^2 - r^2)`` leaves ``r^6 / 16 R^5`` beyond the quartic, 49 um
at ``r = 25`` mm on R 50 (ten times the reading noise), 0.5 um on R 150, 3e-6 mm on R 500. Here the
remainder after the quartic is fitted, per hole, over the sampled disc (radius ``rho``): a polynomial
of degrees 5 to :data:`ORDER` in the local ``(s, t)`` (the terms ``s^a t^b / (a! b!)``, ``a + b = k``,
``a`` from ``k`` down to 0: the convention of the first nine columns of ``higher``), least squares
over the mesh's vertices in the disc (on the CAD surface; a facet is a chord of it). What the fit
leaves (its residual's RMS over the disc, ``u_height`` mm) is the height no model term carries:
truncation beyond :data:`ORDER` and the vertices' own error; :mod:`metrology.measure.remainder` puts it
into each hole's U95.

Run only where the footprint needs it: the remainder a sphere of the hole's largest curvature would
leave at ``rho``, ``|k|^5 rho^6 / 16``, above :data:`NEEDED_MM`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["remainder_terms", "ORDER", "NEEDED_MM", "MAX_VERTICES", "MIN_VERTICES", "extra_exponents"]

#: the highest degree of the fitted remainder (degrees 5..8: 30 terms). Measured on cylinders of R 50 under a
#: 31 mm disc (benchmarks/study_tight_radii.py): the residual after degree 8 is ~1e-4 of the quartic's remainder
ORDER = 8
#: the quartic's remainder at the disc's edge (``|k|^5 rho^6 / 16``, mm) above which it is fitted: 0.1 um, a
#: fiftieth of the reading noise (R 500 under a 34 mm disc: 3e-6 mm, not fitted; R 150: 1.3e-3 mm, fitted)
NEEDED_MM = 1e-4
#: vertices taken in a disc (evenly strided when the mesh has more there): the fit's 30 terms and to spare
MAX_VERTICES = 1500
#: fewer vertices in the disc than this: no fit (the remainder's size is then the hole's ``u_height``)
MIN_VERTICES = 60


def extra_exponents(order: int = ORDER):
    """``[(a, b), ...]``: the exponents of ``s^a t^b`` of degrees 5..order, in column order."""
    return [(k - j, j) for k in range(5, order + 1) for j in range(k + 1)]


def _monomials(s_, t_, exps):
    """``(..., len(exps))``: ``s^a t^b``, from the powers of ``s`` and ``t`` multiplied up once (``**`` for each of
    the 30 columns took 4 ms a hole of 1,500 vertices, 0.2 ms this way; equal to 1 ulp)."""
    top = max(max(a, b) for a, b in exps)
    S, T = [np.ones_like(s_)], [np.ones_like(t_)]
    for _ in range(top):
        S.append(S[-1] * s_)
        T.append(T[-1] * t_)
    return np.stack([S[a] * T[b] for a, b in exps], axis=-1)


def _quartic(coef, s_, t_):
    """Heights (mm) of the local quartic ``coef (15,)`` (:func:`metrology.panel.holes._vertex_cubic`'s columns)."""
    exps = [(0, 0), (1, 0), (0, 1)] + [(k - j, j) for k in range(2, 5) for j in range(k + 1)]  # the same order
    X = np.stack([s_ ** a * t_ ** b / (math.factorial(a) * math.factorial(b)) for a, b in exps], axis=-1)
    return X @ coef


def remainder_terms(panel, P, n, e1, e2, rho: float, coef, k):
    """The remainder beyond the local quartic over each hole's disc.

    Parameters
    ----------
    panel : metrology.panel.mesh.Panel (its mesh's vertices)
    P : (m, 3) float, mm, panel frame, the drill points on the panel; n, e1, e2 : (m, 3) unit, the local frame
    rho : float, mm, the disc's radius
    coef : (m, 15) float, the local quartic's coefficients (heights along ``n``; NaN rows: none)
    k : (m, 2) float, 1/mm, the principal curvatures

    Returns
    -------
    extra : (m, E) float or None, the coefficients of :func:`extra_exponents` (``s, t`` mm); None where no hole
        needs them
    u_height : (m,) float, mm, the height the model leaves (0 where not needed; the quartic's remainder
        ``|k|^5 rho^6 / 16`` where the disc had too few vertices)
    """
    from scipy.spatial import cKDTree

    m = len(P)
    kmax = np.nan_to_num(np.abs(np.asarray(k, float)).max(1)) if len(P) else np.zeros(0)
    bound = kmax ** 5 * rho ** 6 / 16.0  # mm: the quartic's remainder on a sphere of that curvature
    need = np.flatnonzero((bound > NEEDED_MM) & np.all(np.isfinite(coef), axis=1))
    u_height = np.zeros(m)
    if need.size == 0:
        return None, u_height
    V = np.asarray(panel.mesh.vertices, float)
    tree = getattr(panel, "_vertex_tree", None)
    if tree is None:
        tree = panel._vertex_tree = cKDTree(V)
    exps = extra_exponents()
    extra = np.zeros((m, len(exps)))
    # back from the monomials of s / rho, t / rho to the Taylor coefficients of s^a t^b / (a! b!)
    scale = np.array([math.factorial(a) * math.factorial(b) / rho ** (a + b) for a, b in exps])
    for i, near in zip(need, tree.query_ball_point(P[need], r=rho)):
        near = np.asarray(near, int)
        if len(near) > MAX_VERTICES:
            near = near[np.linspace(0, len(near) - 1, MAX_VERTICES).astype(int)]
        if len(near) < MIN_VERTICES:
            u_height[i] = bound[i]
            continue
        q = V[near] - P[i]
        s_, t_, w = q @ e1[i], q @ e2[i], q @ n[i]
        r = w - _quartic(coef[i], s_, t_)
        X = _monomials(s_ / rho, t_ / rho, exps)
        norm = np.sqrt((X * X).sum(0))  # the normal equations of unit columns (30 x 30: a least-squares solve of
        Xn = X / norm  # 1500 x 30 took 0.2 s a hole under load)
        try:
            c = np.linalg.solve(Xn.T @ Xn, Xn.T @ r) / norm
        except np.linalg.LinAlgError:
            u_height[i] = bound[i]
            continue
        res = r - X @ c
        extra[i] = c * scale
        u_height[i] = float(np.sqrt(np.mean(res * res)))
    return extra, u_height

"""The datum's form beyond the plane: a quadratic in the plane's own axes, tested against the noise (F-test)."""

from __future__ import annotations

import math
from dataclasses import replace
import numpy as np
from metrology.core.tolerances import COLLINEAR_RTOL
from metrology.datum.result import DatumForm


def _tls(points):
    """Centroid ``(3,)``, normal ``(3,)`` and scatter eigenvalues/vectors of ``points`` ``(k, 3)``."""
    c = points.mean(axis=0)
    q = points - c
    evals, evecs = np.linalg.eigh(q.T @ q)
    return c, evecs[:, 0], evals, evecs


def _collinear(evals) -> bool:
    """Scatter eigenvalues (ascending) of a collinear or coincident set (in singular values)."""
    s = np.sqrt(np.clip(evals, 0.0, None))
    return bool(s[1] <= COLLINEAR_RTOL * max(s[2], 1e-300))


def _quadratic_in(c, A, b):
    """Coefficients ``(6,)`` of ``q(A x + b)`` for the quadratic ``q`` with coefficients ``c``
    ``(c0, cu, cv, cuu, cuv, cvv)``; ``A`` (2, 2), ``b`` (2,)."""
    H = np.array([[c[3], 0.5 * c[4]], [0.5 * c[4], c[5]]])
    g = np.array([c[1], c[2]])
    Hn = A.T @ H @ A
    gn = A.T @ (g + 2 * H @ b)
    c0 = c[0] + g @ b + b @ H @ b
    return np.array([c0, gn[0], gn[1], Hn[0, 0], 2 * Hn[0, 1], Hn[1, 1]])


def _form(G7, lin, n, length, shift, centroid, axes, sub, selection, threshold):
    """Quadratic form of the residuals from the Gram matrix ``G7`` of
    ``[1, u, v, u^2, u v, v^2, w]`` (``u, v`` scaled by ``length``, selection frame).

    ``lin = (alpha, beta, gamma, delta)`` maps to the final plane's residual
    ``r = alpha + beta u + gamma v + delta w``; the form is fitted to ``r``, then moved
    to the centroid and the final axes (``shift = (A, b)``: ``(u_sel, v_sel) = A (u, v) + b``).
    """
    from scipy.special import fdtrc  # the F distribution's survival function (scipy.stats.f.sf)

    if n < 7:
        return None
    # Gram of [X6, r] from Gram of [X6, w]: r = X6 @ t + delta w
    t = np.zeros(6)
    t[:3] = lin[:3]
    delta = lin[3]
    G = G7[:6, :6]
    gw = G7[:6, 6]
    gvec = G @ t + delta * gw
    rss = float(t @ G @ t + 2 * delta * (t @ gw) + delta * delta * G7[6, 6])
    w = np.linalg.eigvalsh(G)
    if w[0] <= 1e-12 * w[-1]:
        return None
    a = np.linalg.solve(G, gvec)
    rss_q = max(rss - float(gvec @ a), 0.0)
    a_l = np.linalg.solve(G[:3, :3], gvec[:3])
    rss_l = max(rss - float(gvec[:3] @ a_l), 0.0)
    dof2 = n - 6
    s2 = rss_q / dof2
    if s2 > 0:
        f_stat = ((rss_l - rss_q) / 3.0) / s2
        p = float(fdtrc(3, dof2, f_stat))
    else:  # an exact quadric: the quadratic terms explain everything left
        f_stat, p = (math.inf, 0.0) if rss_l > 0 else (0.0, 1.0)
    unscale = np.array([1.0, 1 / length, 1 / length, 1 / length**2, 1 / length**2, 1 / length**2])
    coef = a * unscale
    cov = np.linalg.inv(G) * s2 * np.outer(unscale, unscale)
    # from the selection frame to the centroid and the final axes
    A, b = shift
    T = np.column_stack([_quadratic_in(e, A, b) for e in np.eye(6)])
    coef = T @ coef
    cov = T @ cov @ T.T
    form = DatumForm(
        origin=centroid,
        axes=axes,
        coefficients=coef,
        stderr=np.sqrt(np.clip(np.diag(cov), 0.0, None)),
        f_statistic=float(f_stat),
        p_value=p,
        dof=(3, dof2),
        pv=0.0,
    )
    inl = sub[np.abs(sub @ selection[:3] + selection[3]) <= threshold]
    uv = (inl - centroid) @ axes.T
    z = form.evaluate(uv[:, 0], uv[:, 1])
    return replace(form, pv=float(z.max() - z.min()) if len(z) else 0.0)

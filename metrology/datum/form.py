"""The datum's form: a quadratic surface fitted to the inliers' residuals, with an F-test
of its three quadratic terms against the plane."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["DatumForm", "fit_form", "quadratic_in", "FORM_ALPHA"]

#: significance level of the F-test of the quadratic form (unitless)
FORM_ALPHA = 0.01


@dataclass(frozen=True)
class DatumForm:
    """The quadratic form of the datum over its best-fit plane.

    ``r(u, v) = c0 + cu u + cv v + cuu u^2 + cuv u v + cvv v^2``, ``r`` the signed
    residual (mm, positive on the normal's side), ``(u, v)`` mm along ``axes`` from
    ``origin``.

    Attributes
    ----------
    origin : (3,) float, mm, cloud frame
        The inliers' centroid.
    axes : (2, 3) float, unit, cloud frame
        ``u`` (largest in-plane spread) and ``v``; ``(u, v, normal)`` is right-handed.
    coefficients : (6,) float
        ``c0`` mm, ``cu, cv`` unitless, ``cuu, cuv, cvv`` 1/mm.
    stderr : (6,) float
        1-sigma of ``coefficients``, same units.
    f_statistic : float
        F of the three quadratic terms against the plane, ``(3, n - 6)`` degrees of freedom.
    p_value : float
        Probability of an F this large from a flat datum with Gaussian noise.
    pv : float, mm
        Peak-to-valley of the fitted quadratic surface over the (subsampled) inliers.
    """

    origin: np.ndarray
    axes: np.ndarray
    coefficients: np.ndarray
    stderr: np.ndarray
    f_statistic: float
    p_value: float
    dof: tuple
    pv: float
    alpha: float = FORM_ALPHA

    @property
    def significant(self) -> bool:
        return bool(self.p_value < self.alpha)

    def evaluate(self, u, v):
        """Fitted residual (mm) at in-plane coordinates ``u, v`` (mm, any matching shapes)."""
        c = self.coefficients
        return c[0] + c[1] * u + c[2] * v + c[3] * u * u + c[4] * u * v + c[5] * v * v

    def to_dict(self) -> dict:
        c, s = self.coefficients, self.stderr
        names = ("c0_mm", "cu", "cv", "cuu_per_mm", "cuv_per_mm", "cvv_per_mm")
        return {
            "model": "r = c0 + cu*u + cv*v + cuu*u^2 + cuv*u*v + cvv*v^2 (r, u, v in mm)",
            "origin": [float(x) for x in self.origin],
            "u_axis": [float(x) for x in self.axes[0]],
            "v_axis": [float(x) for x in self.axes[1]],
            "coefficients": {k: float(x) for k, x in zip(names, c)},
            "sigma": {k: float(x) for k, x in zip(names, s)},
            "f_statistic": float(self.f_statistic),
            "dof": [int(self.dof[0]), int(self.dof[1])],
            "p_value": float(self.p_value),
            "alpha": float(self.alpha),
            "significant": self.significant,
            "pv_mm": float(self.pv),
        }



def quadratic_in(c, A, b):
    """Coefficients ``(6,)`` of ``q(A x + b)`` for the quadratic ``q`` with coefficients ``c``
    ``(c0, cu, cv, cuu, cuv, cvv)``; ``A`` (2, 2), ``b`` (2,)."""
    H = np.array([[c[3], 0.5 * c[4]], [0.5 * c[4], c[5]]])
    g = np.array([c[1], c[2]])
    Hn = A.T @ H @ A
    gn = A.T @ (g + 2 * H @ b)
    c0 = c[0] + g @ b + b @ H @ b
    return np.array([c0, gn[0], gn[1], Hn[0, 0], 2 * Hn[0, 1], Hn[1, 1]])


#: the continued fraction of the incomplete beta function: relative tolerance and most terms
#: (it needs about sqrt(max(a, b)) terms: 2300 for a 10^7-point cloud)
_BETACF_EPS = 1e-15
_BETACF_MAX = 200_000


def _betacf(a, b, x):
    """The continued fraction of the regularized incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, _BETACF_MAX):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))):
            d = 1.0 + aa * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + aa / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < _BETACF_EPS:
            return h
    raise ArithmeticError(f"incomplete beta ({a}, {b}, {x}): the continued fraction did not converge")


def _lgamma_ratio(a, b):
    """``ln Gamma(a + b) - ln Gamma(a)``; for large ``a`` by the difference of Stirling's series
    (the plain difference of two lgamma values near 10^8 keeps only 8 digits)."""
    if a < 1e4:
        return math.lgamma(a + b) - math.lgamma(a)
    c = a + b
    return ((a - 0.5) * math.log1p(b / a) + b * math.log(c) - b
            + (1.0 / c - 1.0 / a) / 12.0 - (1.0 / c**3 - 1.0 / a**3) / 360.0)


def _betainc(a, b, x, y):
    """Regularized incomplete beta function ``I_x(a, b)``, ``a, b > 0``, ``0 <= x <= 1``;
    ``y = 1 - x`` given by the caller (exact where x is near 1)."""
    if x <= 0.0:
        return 0.0
    if y <= 0.0:
        return 1.0
    big, small = max(a, b), min(a, b)
    log_front = (_lgamma_ratio(big, small) - math.lgamma(small) + a * (math.log1p(-y) if y < 0.5 else math.log(x))
                 + b * (math.log1p(-x) if x < 0.5 else math.log(y)))
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _betacf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _betacf(b, a, y) / b


def f_sf(d1, d2, f):
    """Survival function of the F distribution, ``P(F(d1, d2) > f)`` (scipy's ``fdtrc``).

    metro's own (the continued fraction of Numerical Recipes' ``betai``, checked against
    scipy in the tests): ``scipy.special`` takes 0.2 s to import, a third of a whole
    ``metro fit-plane`` run."""
    if not f > 0.0:
        return 1.0
    if math.isinf(f):
        return 0.0
    return _betainc(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * f), d1 * f / (d2 + d1 * f))


def fit_form(G7, lin, n, length, shift, centroid, axes, sub, selection, threshold):
    """Quadratic form of the residuals from the Gram matrix ``G7`` of
    ``[1, u, v, u^2, u v, v^2, w]`` (``u, v`` scaled by ``length``, selection frame).

    ``lin = (alpha, beta, gamma, delta)`` maps to the final plane's residual
    ``r = alpha + beta u + gamma v + delta w``; the form is fitted to ``r``, then moved
    to the centroid and the final axes (``shift = (A, b)``: ``(u_sel, v_sel) = A (u, v) + b``).
    """
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
        p = float(f_sf(3, dof2, f_stat))
    else:  # an exact quadric: the quadratic terms explain everything left
        f_stat, p = (math.inf, 0.0) if rss_l > 0 else (0.0, 1.0)
    unscale = np.array([1.0, 1 / length, 1 / length, 1 / length**2, 1 / length**2, 1 / length**2])
    coef = a * unscale
    cov = np.linalg.inv(G) * s2 * np.outer(unscale, unscale)
    # from the selection frame to the centroid and the final axes
    A, b = shift
    T = np.column_stack([quadratic_in(e, A, b) for e in np.eye(6)])
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


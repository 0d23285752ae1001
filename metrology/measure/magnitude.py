"""The expanded uncertainty of an angle that is the length of a 2-D tilt.

A hole's angle to the drill axis is the length of its tilt, a 2-D vector ``g`` (rad, the TCS
``x, y``) measured with a Gaussian error of covariance ``C`` (2 x 2, rad^2). Far from zero
(``|g|`` many standard deviations) the length's error is the error along ``g``, normal, and
``U95 = K95 sqrt(g^T C g) / |g|``. After the cell's adjustment the true angle is of the order of
that standard deviation itself, and the length's error is not normal: with the tilt's true
value ``t``, ``|g| - |t|`` has a Rice distribution (isotropic ``C``), or its anisotropic
generalisation. A constant factor cannot fit both ends: the 2-D radius (``K95_2D``, 2.45 sigma)
holds the whole 2-D error and over-covers the length (about 98 % when the true angle is of the
order of sigma), the 1-D factor (1.96) under-covers near zero.

**U95 here** is the half-width ``q`` of the interval ``|g| +- q`` that holds 95 % of the length
``|t|`` of a tilt ``t ~ N(g, C)`` (the measured tilt and its covariance: the distribution of the
true tilt given the measurement, uniform prior over the plane):

    P( | |t| - |g| | <= q ) = 0.95,    t ~ N(g, C).

For isotropic ``C = sigma^2 I`` this is ``P(|R - nu| <= q) = 0.95`` with ``R ~ Rice(nu, sigma)``
and ``nu = |g|``. It is 2.45 sigma at ``|g| = 0`` (the 2-D radius), falls below 1.96 sigma near
``|g| = 1.5 sigma`` (the length is compressed there) and tends to ``K95 sigma`` far out. Its
frequentist coverage over the true length (tests/measure/test_magnitude.py, on the forward
simulator in benchmarks/study_measure.py): 95 % for a true angle of a few sigma or more, near
95 % when the true angle is itself a 2-D normal of the measurement's spread (a cell's adjustment),
lower (about 82 %) if the true angle is exactly 0.

**Computation.** In the frame of ``C``'s eigenvectors (``l1 >= l2``) the answer, in units of
``sqrt(l1)``, depends on ``x = |g| / sqrt(l1)``, ``s = sqrt(l2 / l1)`` and the direction of ``g``,
given as ``w = (u - s) / (1 - s)`` with ``u = sqrt(g^T C g / l1) / |g|`` the radial standard
deviation (``w = 1``: ``g`` along the major axis, 0: along the minor; far out
``q = K95 sqrt(l1) u``, bilinear in ``s, w``). ``q / sqrt(l1)`` is tabulated on a grid of ``x, s,
w`` and interpolated linearly (within 2 % everywhere, 0.7 % at the 99th percentile of random
``x, s, w``; the table ships as ``metrology/data/magnitude_u95.npy``, written by
:func:`compute_table`: the major axis's integral exactly with the normal CDF, the minor axis's on
:data:`NODES` points, bisection in ``q``; tests/measure/test_magnitude.py recomputes grid
points). Beyond ``x = X_MAX`` the linear rule is used.
"""

from __future__ import annotations

import functools

import numpy as np

from metrology.core.sym2 import eig2

__all__ = ["K95", "major_sd", "magnitude_u95", "normal_uniform_u95", "normal_spread_u95", "SPREAD_VARIANCE",
           "compute_table", "X_MAX", "TABLE_FILE"]

#: the 95 % quantile of |N(0, 1)|, the coverage factor of a normal (re-exported by measure.normals)
K95 = 1.959963984540054
#: beyond this many major-axis standard deviations the length's error is the radial one (normal):
#: the tabulated q is within 0.5 % of ``K95 sqrt(g^T C g) / |g|`` there on the grid's ratios
X_MAX = 24.0
#: the grid of x = |g| / sqrt(l1), of s = sqrt(l2 / l1) and of w (the module docstring)
GRID_X = np.concatenate([np.arange(0.0, 4.0, 0.125), np.arange(4.0, 8.0, 0.25), np.arange(8.0, X_MAX + 0.5, 1.0)])
GRID_S = np.linspace(0.0, 1.0, 16)
GRID_W = np.linspace(0.0, 1.0, 16)
#: points of the minor axis's integral (uniform over +-8 standard deviations, trapezoidal; 961
#: points: q within 1e-3 sqrt(l1) of 3841 points on random x, r, phi)
NODES = 961
#: the stored table, ``metrology/data/<TABLE_FILE>``
TABLE_FILE = "magnitude_u95.npy"


def _annulus(m1, m2, r, a, b):
    """P(a <= |m + e| <= b), ``e ~ N(0, diag(1, r))``; arrays of one shape (a <= b)."""
    from scipy.special import ndtr

    z = np.linspace(-8.0, 8.0, NODES)
    w = np.exp(-0.5 * z * z)
    w /= w.sum()
    y = m2[..., None] + np.sqrt(r)[..., None] * z  # the minor coordinate of m + e
    y2 = y * y

    def inside(rho):
        h = np.sqrt(np.clip(rho[..., None] ** 2 - y2, 0.0, None))
        m = m1[..., None]
        return ((ndtr(h - m) - ndtr(-h - m)) * w).sum(-1)

    return inside(b) - inside(np.maximum(a, 0.0))


def _solve(x, r, phi, p=0.95, iterations=40):
    """``q`` (unit: the major axis's standard deviation) with ``P(| |t| - x | <= q) = p``,
    ``t ~ N(x (cos phi, sin phi), diag(1, r))``: bisection, arrays of one shape."""
    m1, m2 = x * np.cos(phi), x * np.sin(phi)
    lo, hi = np.zeros_like(x), np.full_like(x, 4.0)
    for _ in range(iterations):
        q = 0.5 * (lo + hi)
        low = _annulus(m1, m2, r, x - q, x + q) < p
        lo, hi = np.where(low, q, lo), np.where(low, hi, q)
    return 0.5 * (lo + hi)


def _phi(s, w):
    """The angle (rad) between ``g`` and the major axis for ``s = sqrt(l2 / l1)`` and ``w``."""
    r = s * s
    u = s + w * (1.0 - s)
    with np.errstate(invalid="ignore", divide="ignore"):
        c2 = np.where(r < 1.0, (u * u - r) / (1.0 - r), 1.0)
    return np.arccos(np.sqrt(np.clip(c2, 0.0, 1.0)))


def compute_table():
    """(len(GRID_X), len(GRID_S), len(GRID_W)) float: ``q / sqrt(l1)`` on the grid (about a minute;
    ``python -m metrology.measure.magnitude`` writes it to the package's data)."""
    X, S, W = np.meshgrid(GRID_X, GRID_S, GRID_W, indexing="ij")
    return _solve(X, S * S, _phi(S, W))


@functools.lru_cache(maxsize=1)
def _table():
    from metrology.io.data import data_path

    t = np.load(data_path(TABLE_FILE))
    if t.shape != (len(GRID_X), len(GRID_S), len(GRID_W)):
        raise RuntimeError(f"{data_path(TABLE_FILE)}: shape {t.shape}, the grid needs "
                           f"{(len(GRID_X), len(GRID_S), len(GRID_W))}: run python -m metrology.measure.magnitude")
    return t


def major_sd(C):
    """The standard deviation along the major axis of 2-D spreads: ``sqrt`` of the larger eigenvalue.

    Parameters
    ----------
    C : (N, 2, 2) float, rad^2, symmetric covariances

    Returns
    -------
    (N,) float, rad
    """
    C = np.asarray(C, float).reshape(-1, 2, 2)
    return np.sqrt(eig2(C[:, 0, 0], C[:, 0, 1], C[:, 1, 1])[0])


def _lookup(x, s, w):
    """(N,) float: ``q / sqrt(l1)`` interpolated linearly in the table at the points ``x, s, w``
    (N,) within the grid. ``scipy.ndimage.map_coordinates`` at the points' fractional indices (each
    grid is uniform piecewise, so interpolating the indices over it is exact) does what
    ``RegularGridInterpolator`` does, whose ``scipy.interpolate`` would import ``scipy.optimize``,
    ``sparse`` and ``linalg`` into every worker for this one lookup (tests/measure/test_magnitude.py
    compares the two)."""
    from scipy.ndimage import map_coordinates

    index = np.stack([np.interp(v, grid, np.arange(len(grid), dtype=float))
                      for v, grid in ((x, GRID_X), (s, GRID_S), (w, GRID_W))])
    return map_coordinates(_table(), index, order=1, mode="nearest")


def magnitude_u95(g, C):
    """U95 of the length of 2-D tilts (see the module docstring).

    Parameters
    ----------
    g : (N, 2) float, rad, the measured tilts (their lengths are the angles)
    C : (N, 2, 2) float, rad^2, the tilts' covariances

    Returns
    -------
    (N,) float, rad: the half-width of ``|g| +- U95`` holding 95 % of the true length
    (NaN where ``C`` or ``g`` is not finite)
    """
    g = np.asarray(g, float).reshape(-1, 2)
    C = np.asarray(C, float).reshape(-1, 2, 2)
    a, b, c = C[:, 0, 0], C[:, 0, 1], C[:, 1, 1]
    l1, l2 = eig2(a, b, c)
    l2 = np.maximum(l2, 0.0)
    gn = np.hypot(g[:, 0], g[:, 1])
    s1 = np.sqrt(l1)
    with np.errstate(invalid="ignore", divide="ignore"):
        x = gn / s1
        sr = np.sqrt(np.clip(l2 / l1, 0.0, 1.0))
        radial = np.sqrt(np.maximum(g[:, 0] * g[:, 0] * a + 2 * g[:, 0] * g[:, 1] * b + g[:, 1] * g[:, 1] * c,
                                    0.0)) / gn  # rad: the standard deviation along g
        w = np.where(sr < 1.0, (radial / s1 - sr) / (1.0 - sr), 1.0)
    w = np.where(np.isfinite(w), np.clip(w, 0.0, 1.0), 1.0)  # |g| = 0: any direction (q does not depend on it)
    out = np.full(len(g), np.nan)
    ok = np.isfinite(x) & np.isfinite(sr) & (l1 > 0)
    near = ok & (x < X_MAX)
    if near.any():
        out[near] = s1[near] * _lookup(x[near], sr[near], w[near])
    far = ok & ~near
    out[far] = K95 * radial[far]
    out[np.isfinite(gn) & (l1 == 0)] = 0.0
    return out


def _normal_uniform_p(q, s, a):
    """P(|X + Y| <= q), X ~ N(0, s^2), Y uniform on [-a, a] (a > 0): the mean over Y of the normal's
    probability, with the integral of the normal CDF in closed form (``int Phi = x Phi(x) + phi(x)``)."""
    from scipy.special import ndtr

    def F(x):  # int_0^x Phi(t) dt + const
        return x * ndtr(x) + np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi)

    return s / (2.0 * a) * (F((q + a) / s) - F((q - a) / s) - F((-q + a) / s) + F((-q - a) / s))


@functools.lru_cache(maxsize=1)
def _normal_uniform_table():
    """``k(t)`` on 201 points of ``t = a / sqrt(s^2 + a^2)`` in [0, 1]: ``q = k sqrt(s^2 + a^2 / 3)``."""
    t = np.linspace(0.0, 1.0, 201)
    a = np.where(t < 1.0, t, 1.0)
    s = np.where(t < 1.0, np.sqrt(1.0 - t * t), 0.0)
    u = np.sqrt(s * s + a * a / 3.0)
    lo, hi = np.zeros_like(t), np.full_like(t, 4.0)
    for _ in range(60):
        q = 0.5 * (lo + hi) * u
        with np.errstate(invalid="ignore", divide="ignore"):
            p = np.where(t == 0.0, 2.0 * _ndtr(q) - 1.0,
                         np.where(t == 1.0, np.clip(q / np.where(a > 0, a, 1.0), 0.0, 1.0),
                                  _normal_uniform_p(q, np.where(s > 0, s, 1.0), np.where(a > 0, a, 1.0))))
        low = p < 0.95
        lo, hi = np.where(low, 0.5 * (lo + hi), lo), np.where(low, hi, 0.5 * (lo + hi))
    return t, 0.5 * (lo + hi)


def _ndtr(x):
    from scipy.special import ndtr

    return ndtr(x)


def normal_uniform_u95(sigma, a):
    """U95 of the sum of a normal error (standard deviation ``sigma``) and a uniform one on
    ``[-a, a]`` (arrays, one unit): the half-width ``q`` with ``P(|X + Y| <= q) = 0.95``. From
    ``K95 sigma`` (``a = 0``) to ``0.95 a`` (``sigma = 0``); the linear rule ``K95 sqrt(sigma^2 +
    a^2 / 3)`` would over-cover where the uniform term dominates (GUM 4.3.7's rectangular
    distribution is not normal: 1.96 / 1.65 of what it needs)."""
    sigma = np.asarray(sigma, float)
    a = np.abs(np.asarray(a, float))
    t_grid, k = _normal_uniform_table()
    with np.errstate(invalid="ignore", divide="ignore"):
        t = a / np.sqrt(sigma * sigma + a * a)
    t = np.where(np.isfinite(t), t, 0.0)
    return np.interp(t, t_grid, k) * np.sqrt(sigma * sigma + a * a / 3.0)


#: the variance of an error within ``+-a`` over ``a^2``, by what is known of it: ``uniform`` spread evenly (GUM 4.3.7),
#: ``arcsine`` a sine between the bounds (U-shaped: JCGM 101 6.4.6), ``edge`` any distribution within them (its worst
#: case: all of it at a bound; a^2 is the largest variance any distribution within +-a has)
SPREAD_VARIANCE = {"uniform": 1.0 / 3.0, "arcsine": 0.5, "edge": 1.0}
#: nodes of the arcsine's mean over its phase (midpoints; q within 1e-4 of 8192 nodes on the table's grid)
ARCSINE_NODES = 2048


def _spread_p(q, s, a, shape):
    """P(|X + Y| <= q), X ~ N(0, s^2), Y within [-a, a] as ``shape`` (:data:`SPREAD_VARIANCE`): uniform, arcsine
    (``a sin theta``, theta uniform), or edge (the worst case: ``Y = a``, where the probability is the least for a
    symmetric unimodal X). Arrays of one shape, ``s > 0``."""
    from scipy.special import ndtr

    if shape == "uniform":
        return _normal_uniform_p(q, s, np.where(a > 0, a, 1e-300))
    if shape == "edge":
        return ndtr((q - a) / s) - ndtr((-q - a) / s)
    y = a[..., None] * np.sin(np.pi * ((np.arange(ARCSINE_NODES) + 0.5) / ARCSINE_NODES - 0.5))
    qq, ss = q[..., None], s[..., None]
    return (ndtr((qq - y) / ss) - ndtr((-qq - y) / ss)).mean(-1)


@functools.lru_cache(maxsize=4)
def _spread_table(shape):
    """``k(phi)`` on 401 points of ``phi = atan2(a, s)`` in ``[0, pi/2]``: ``q = k sqrt(s^2 + v a^2)`` (v the shape's
    variance, :data:`SPREAD_VARIANCE`); ``phi = pi/2`` (no normal part) from the spread's own 95 % half-width
    (uniform 0.95 a, arcsine ``a sin(0.95 pi / 2)``, edge a)."""
    phi = np.linspace(0.0, 0.5 * np.pi, 401)
    a, s = np.sin(phi), np.cos(phi)
    v = SPREAD_VARIANCE[shape]
    u = np.sqrt(s * s + v * a * a)
    inner = phi < 0.5 * np.pi
    lo, hi = np.zeros(inner.sum()), np.full(inner.sum(), 4.0)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        low = _spread_p(mid * u[inner], s[inner], a[inner], shape) < 0.95
        lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
    k = np.empty_like(phi)
    k[inner] = 0.5 * (lo + hi)
    k[~inner] = {"uniform": 0.95, "arcsine": np.sin(0.475 * np.pi), "edge": 1.0}[shape] / np.sqrt(v)
    return phi, k


def normal_spread_u95(sigma, a, shape):
    """U95 of the sum of a normal error (standard deviation ``sigma``) and one within ``[-a, a]`` distributed as
    ``shape`` (``uniform``, ``arcsine``, or ``edge``: any distribution within the bounds, its U95 the least that
    holds 95 % whatever it is; :data:`SPREAD_VARIANCE`), arrays of one unit: the half-width ``q`` with
    ``P(|X + Y| <= q) >= 0.95``. ``edge`` runs from ``K95 sigma`` to ``a + 1.645 sigma`` (``a`` large); the
    uniform's is :func:`normal_uniform_u95`."""
    if shape == "uniform":
        return normal_uniform_u95(sigma, a)
    sigma = np.asarray(sigma, float)
    a = np.abs(np.asarray(a, float))
    phi_grid, k = _spread_table(shape)
    phi = np.arctan2(a, sigma)
    return np.interp(phi, phi_grid, k) * np.sqrt(sigma * sigma + SPREAD_VARIANCE[shape] * a * a)


if __name__ == "__main__":
    from metrology.io.data import DATA_DIR

    np.save(DATA_DIR / TABLE_FILE, compute_table())

"""The robust datum-plane fit: RANSAC for the inliers, total least squares on them, the
fit's uncertainty and the datum's form.

The procedure (:func:`fit_plane_robust`), for a cloud of ``m`` points:

1. **Subsample.** RANSAC and the threshold search run on at most :data:`RANSAC_MAX_POINTS`
   points drawn without replacement by a seeded ``numpy.random.Generator`` (all points
   when there are fewer). When most points are inliers, a subsample finds the plane as
   surely as the whole cloud, at a fraction of the cost.
2. **Robust scale** (when no threshold is given). A least-quantile-of-squares search:
   :data:`LQS_HYPOTHESES` planes through random point triples, each scored by the
   :data:`LQS_QUANTILE` quantile of the absolute residuals of :data:`LQS_POINTS` points;
   the best gives a first noise scale ``sigma`` (breakdown point 75 %: up to three
   points in four may be outliers). The threshold is ``INLIER_K_SIGMA * sigma``.
3. **RANSAC.** Open3D's ``segment_plane`` on the subsample, with Open3D's generator
   seeded from the same ``Generator`` (Open3D >= 0.19 is deterministic once seeded).
4. **Refinement** on the subsample: inliers within the threshold -> total-least-squares
   plane -> (default threshold only) ``sigma`` re-estimated from the inliers' residuals,
   corrected for the truncation at ``+-K sigma`` so that it is consistent for Gaussian
   noise -> threshold ``K sigma`` -> repeat until the inlier set and threshold settle.
   This converges on the noise of the datum from a scale too small or too large.
5. **One pass over all points** (chunked, so memory stays flat): select the inliers
   within the threshold of the refined plane, accumulate their count, sum and scatter
   matrix about a reference point; the total-least-squares plane is the eigenvector of
   the smallest eigenvalue of the scatter.
6. **A second pass over the inliers**: residuals to the final plane (RMS, min, max,
   peak-to-valley) and the normal equations of the quadratic form
   ``r(u, v) = c0 + cu u + cv v + cuu u^2 + cuv u v + cvv v^2`` in the plane's own
   axes ``(u, v)`` about the centroid, with an F-test of the three quadratic terms
   against the plane.

Uncertainty: first-order covariance of the total-least-squares plane from the residual
scatter of the inliers, ``sigma^2 = sum r^2 / (n - 3)``: the tilt of the normal towards
in-plane axis ``e_i`` has variance ``sigma^2 / lambda_i`` (``lambda_i`` the inliers'
scatter along ``e_i``), and the plane's position at the centroid ``sigma^2 / n``; then
multiplied by ``1 / g(k)^4`` (1.056 for the default window ``k = 3``), the sandwich
variance of least squares inside a window that follows the fit (see
:func:`window_sigmas`). Without that factor the normal's uncertainty came out 4 % low
in 2000 seeded trials. It assumes independent residuals; a datum with significant form
(see ``form``) makes it describe the best-fit plane of that datum, not a flat one.
With few points (``residual_dof`` small) the 1-sigma values are estimates from
``n - 3`` degrees of freedom: use Student-t factors for coverage.

The sign convention is :class:`metrology.plane.Plane`'s: unit normal, ``D <= 0``.
"""

from __future__ import annotations

import contextlib
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from metrology.core.plane import Plane
from metrology.core.tolerances import COLLINEAR_RTOL

__all__ = [
    "PlaneFit",
    "PlaneForm",
    "fit_plane_robust",
    "fit_plane_file",
    "plot_residuals",
    "lqs_scale",
    "truncated_normal_std",
    "window_sigmas",
]

#: default inlier threshold, in robust standard deviations of the residuals (unitless)
INLIER_K_SIGMA = 3.0
#: RANSAC and the threshold search run on a seeded subsample of at most this many points
RANSAC_MAX_POINTS = 20_000
#: maximum RANSAC hypotheses; Open3D stops earlier once it has found, with probability
#: RANSAC_PROBABILITY, a hypothesis of all inliers
RANSAC_ITERATIONS = 1000
RANSAC_PROBABILITY = 0.99999999
#: least-quantile-of-squares search: points scored, plane hypotheses, and the quantile
#: of absolute residuals minimised (0.25: breakdown at 75 % outliers)
LQS_POINTS = 1000
LQS_HYPOTHESES = 500
LQS_QUANTILE = 0.25
#: a fit whose inliers are less than this share of the cloud is refused (unitless)
MIN_INLIER_RATIO = 0.2
#: a fit whose inliers are thicker (RMS about the plane) than this share of their
#: smallest in-plane RMS spread is refused: the cloud is not a plate (unitless)
MAX_THICKNESS_RATIO = 0.05
#: smallest default threshold, mm (a noise-free synthetic cloud would otherwise get 0)
THRESHOLD_FLOOR_MM = 1e-6
#: significance level of the F-test of the quadratic form (unitless)
FORM_ALPHA = 0.01
#: refinement rounds on the subsample, at most
REFINE_MAX = 50
#: the default-threshold refinement starts at this multiple of RANSAC's threshold (unitless)
REFINE_START = 3.0
#: points per chunk in the passes over the whole cloud
_CHUNK = 1 << 17

SIGN_CONVENTION = "A^2 + B^2 + C^2 = 1 and D <= 0: the normal points from the frame origin towards the plane"


def truncated_normal_std(k: float) -> float:
    """Standard deviation of a standard normal variable truncated to ``[-k, k]`` (unitless)."""
    phi = math.exp(-0.5 * k * k) / math.sqrt(2 * math.pi)
    mass = math.erf(k / math.sqrt(2))
    return math.sqrt(1.0 - 2.0 * k * phi / mass)


def window_sigmas(threshold: float, sigma_kept: float) -> float:
    """The window half-width ``k`` (in noise sigmas) that leaves Gaussian residuals
    truncated to ``+-threshold`` with standard deviation ``sigma_kept``.

    Solves ``g(k) / k = sigma_kept / threshold`` (``g`` = :func:`truncated_normal_std`),
    decreasing from ``1/sqrt(3)`` at ``k -> 0`` (residuals filling the window evenly) to 0.
    Clamped to ``[1, 40]``: below 1 the Gaussian model does not describe the residuals,
    above 40 the window is wide open. Unitless.
    """
    if not (threshold > 0) or not (sigma_kept >= 0):
        return math.inf
    target = sigma_kept / threshold
    lo, hi = 1.0, 40.0
    if target >= truncated_normal_std(lo) / lo:
        return lo
    if target <= truncated_normal_std(hi) / hi:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if truncated_normal_std(mid) / mid > target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class PlaneForm:
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


@dataclass(frozen=True)
class PlaneFit:
    """The result of :func:`fit_plane_robust`.

    Attributes
    ----------
    plane : Plane
        In the cloud frame; unit normal, ``D <= 0``.
    covariance : (4, 4) float
        Covariance of ``(A, B, C, D)``: unitless for the normal, mm for D.
    centroid : (3,) float, mm, cloud frame
        Centroid of the inliers (the plane passes through it).
    axes : (2, 3) float, unit, cloud frame
        In-plane axes: largest and smallest spread of the inliers.
    n_points, n_inliers : int
    threshold : float, mm
        Inlier threshold on the absolute distance to the plane.
    threshold_auto : bool
        True when the threshold was derived from the data (``INLIER_K_SIGMA`` robust sigma).
    noise_sigma : float, mm
        ``sqrt(sum r^2 / (n_inliers - 3))`` over the inliers (NaN with 3 inliers).
    rms, residual_min, residual_max : float, mm
        Of the inliers' signed residuals to ``plane``.
    form : PlaneForm or None
        None when there are too few inliers (< 7) or they do not span the plane.
    seed : int
    ransac_points : int
        Size of the subsample RANSAC ran on.
    selection_plane : (4,) float
        The plane (A, B, C, D) the inliers were selected against (the refined subsample
        plane); :meth:`inliers` uses it to recover the exact inlier set.
    window_k : float
        The inlier band in noise sigmas (:func:`window_sigmas`); the covariance carries
        the factor ``1 / g(window_k)^4``.
    source, format : str
        The file fitted and its format, when fitted from a file.
    """

    plane: Plane
    covariance: np.ndarray
    centroid: np.ndarray
    axes: np.ndarray
    n_points: int
    n_inliers: int
    threshold: float
    threshold_auto: bool
    noise_sigma: float
    rms: float
    residual_min: float
    residual_max: float
    form: PlaneForm | None
    seed: int
    ransac_points: int
    selection_plane: np.ndarray = field(repr=False)
    window_k: float = math.inf
    source: str = ""
    format: str = ""

    @property
    def inlier_ratio(self) -> float:
        return self.n_inliers / self.n_points

    @property
    def flatness(self) -> float:
        """Peak-to-valley of the inliers' residuals to the fitted plane, mm."""
        return self.residual_max - self.residual_min

    @property
    def max_abs_residual(self) -> float:
        return max(abs(self.residual_min), abs(self.residual_max))

    @property
    def normal_sigma(self) -> float:
        """RMS angular error of the normal, rad: ``sqrt(trace of the normal's covariance)``."""
        return float(math.sqrt(max(np.trace(self.covariance[:3, :3]), 0.0)))

    @property
    def offset_sigma(self) -> float:
        """1-sigma of D, mm (includes the normal's tilt acting over the centroid's lever arm)."""
        return float(math.sqrt(max(self.covariance[3, 3], 0.0)))

    @property
    def offset_sigma_at_centroid(self) -> float:
        """1-sigma of the plane's position along its normal at the centroid, mm."""
        inflate = truncated_normal_std(self.window_k) ** -4 if math.isfinite(self.window_k) else 1.0
        return float(self.noise_sigma * math.sqrt(inflate / self.n_inliers))

    def residuals(self, points):
        """Signed distances ``(m,)`` mm of ``points`` ``(m, 3)`` mm, cloud frame, to the plane."""
        return self.plane.distance(points)

    def inliers(self, points):
        """Boolean mask ``(m,)`` of the inliers among ``points`` ``(m, 3)`` mm (the cloud fitted)."""
        n, d = self.selection_plane[:3], self.selection_plane[3]
        return np.abs(np.asarray(points, dtype=float) @ n + d) <= self.threshold

    def to_dict(self) -> dict:
        """Plain-JSON view (degrees named ``_deg``; NaN as None). ``normal`` and ``offset``
        are what :meth:`metrology.plane.Plane.from_json` reads."""

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        out = {
            "schema": "metro.plane/1",
            "source": self.source,
            "format": self.format,
            "frame": "cloud",
            "units": "mm",
            "normal": [float(x) for x in self.plane.normal],
            "offset": float(self.plane.offset),
            "sign_convention": SIGN_CONVENTION,
            "centroid": [float(x) for x in self.centroid],
            "n_points": int(self.n_points),
            "n_inliers": int(self.n_inliers),
            "inlier_ratio": float(self.inlier_ratio),
            "threshold_mm": float(self.threshold),
            "threshold_source": f"auto: {INLIER_K_SIGMA:g} x robust sigma" if self.threshold_auto else "user",
            "noise_sigma_mm": num(self.noise_sigma),
            "residual_dof": int(self.n_inliers - 3),
            "window_sigmas": num(self.window_k),
            "rms_mm": float(self.rms),
            "max_abs_residual_mm": float(self.max_abs_residual),
            "flatness_mm": float(self.flatness),
            "normal_sigma_deg": num(math.degrees(self.normal_sigma)),
            "offset_sigma_mm": num(self.offset_sigma),
            "offset_sigma_at_centroid_mm": num(self.offset_sigma_at_centroid),
            "covariance": [[num(x) for x in row] for row in self.covariance],
            "form": None if self.form is None else self.form.to_dict(),
            "seed": int(self.seed),
            "ransac_points": int(self.ransac_points),
        }
        return out


# ---------------------------------------------------------------------------------------
# pure array functions


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


def lqs_scale(points, rng, n_hypotheses=LQS_HYPOTHESES, quantile=LQS_QUANTILE):
    """Least-quantile-of-squares plane and its Gaussian-consistent residual scale.

    Parameters
    ----------
    points : (k, 3) float, mm, cloud frame; k >= 4
    rng : numpy.random.Generator
    n_hypotheses : int
        Planes tried, each through 3 random points.
    quantile : float
        Quantile of the absolute residuals minimised, in (0, 1).

    Returns
    -------
    sigma : float, mm
        ``Q_q(|r|) / Phi^-1((1 + q) / 2)`` for the best plane (the 3 points defining each
        plane are left out of its quantile).
    plane : (4,) float
        ``(A, B, C, D)`` of the best hypothesis.
    """
    pts = np.asarray(points, dtype=float)
    k = len(pts)
    if k < 4:
        raise ValueError(f"need at least 4 points for a robust scale, got {k}")
    tri = np.sort(rng.integers(0, k, size=(n_hypotheses, 3)), axis=1)
    p0, p1, p2 = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    nrm = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(nrm, axis=1)
    span = np.maximum(np.linalg.norm(p1 - p0, axis=1), np.linalg.norm(p2 - p0, axis=1))
    ok = (length > COLLINEAR_RTOL * span**2) & (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2])
    if not ok.any():
        raise ValueError("points are collinear (or coincident): no unique plane")
    nrm = nrm[ok] / length[ok, None]
    d = -np.einsum("ij,ij->i", nrm, p0[ok])
    ref = pts.mean(axis=0)
    absr = np.abs((pts - ref) @ nrm.T + (d + nrm @ ref))  # (k, h), referred to the centroid
    # the 3 defining points have r = 0: skip them in the order statistic
    rank = min(k - 1, 3 + int(math.ceil(quantile * (k - 3))) - 1)
    qv = np.partition(absr, rank, axis=0)[rank]
    best = int(np.argmin(qv))
    z = _norm_ppf(0.5 * (1.0 + quantile))
    return float(qv[best] / z), np.append(nrm[best], d[best])


def _norm_ppf(p: float) -> float:
    """Standard normal quantile (bisection on erf; used for a handful of constants)."""
    lo, hi = -10.0, 10.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if 0.5 * (1 + math.erf(mid / math.sqrt(2))) < p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _ransac(sub, threshold, rng):
    from metrology.io._o3d import open3d

    o3d = open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(sub))
    o3d.utility.random.seed(int(rng.integers(0, 2**31 - 1)))
    model, idx = cloud.segment_plane(
        distance_threshold=float(threshold), ransac_n=3, num_iterations=RANSAC_ITERATIONS, probability=RANSAC_PROBABILITY
    )
    model = np.asarray(model, dtype=float).ravel()
    scale = np.linalg.norm(model[:3])
    if len(idx) < 3 or not np.isfinite(model).all() or scale == 0:
        raise ValueError(f"RANSAC found no plane with 3 or more points within {threshold:.3g} mm: the cloud is all outliers")
    return model[:3] / scale, float(model[3] / scale)


def _refine(sub, normal, offset, threshold, auto):
    """Alternate inlier selection and TLS on the subsample (and, if ``auto``, the threshold)."""
    g = truncated_normal_std(INLIER_K_SIGMA)
    mask = None
    for _ in range(REFINE_MAX):
        new = np.abs(sub @ normal + offset) <= threshold
        k = int(new.sum())
        if k < 3:
            raise ValueError(f"fewer than 3 points within {threshold:.3g} mm of the best plane: the cloud is all outliers")
        c, normal, _, _ = _tls(sub[new])
        offset = -float(normal @ c)
        new_t = threshold
        if auto:
            r = sub[new] @ normal + offset
            sigma = math.sqrt(float(r @ r) / max(k - 3, 1)) / g
            new_t = max(INLIER_K_SIGMA * sigma, THRESHOLD_FLOOR_MM)
        # the same inliers give the same plane and threshold: a fixed point
        settled = mask is not None and np.array_equal(new, mask)
        mask, threshold = new, new_t
        if settled:
            break
    return normal, offset, threshold


def fit_plane_robust(points, threshold_mm=None, seed=0) -> PlaneFit:
    """Fit the datum plane to a cloud with gross outliers.

    Parameters
    ----------
    points : (m, 3) float, mm, cloud frame
        m >= 3, finite, not collinear.
    threshold_mm : float or None
        Inlier threshold on the distance to the plane, mm; None derives it from the data
        (``INLIER_K_SIGMA`` times a robust residual scale).
    seed : int
        Seed of the ``numpy.random.Generator`` driving the subsample, the robust scale
        and Open3D's RANSAC. Same seed and points, same result, to the bit.

    Returns
    -------
    PlaneFit

    Raises
    ------
    ValueError
        Fewer than 3 points, NaN/inf, collinear points, a bad threshold or seed, or no
        plane (inliers under ``MIN_INLIER_RATIO`` of the cloud, or a cloud as thick as wide).
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be an (m, 3) array of x, y, z, got shape {pts.shape}")
    m = len(pts)
    if m < 3:
        raise ValueError(f"{m} point{'s' if m != 1 else ''}, need at least 3")
    if threshold_mm is not None:
        threshold_mm = float(threshold_mm)
        if not math.isfinite(threshold_mm) or threshold_mm <= 0:
            raise ValueError(f"threshold {threshold_mm} mm: expected a positive distance in mm")
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed {seed}: expected a non-negative integer")
    seed = int(seed)
    rng = np.random.default_rng(seed)
    auto = threshold_mm is None

    if m > RANSAC_MAX_POINTS:
        sub = pts[np.sort(rng.choice(m, RANSAC_MAX_POINTS, replace=False))]
    else:
        sub = pts
    bad = ~np.isfinite(sub).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"a point is {sub[i].tolist()}: coordinates must be finite (no NaN or inf)")
    c_sub, _, ev_sub, ev_vec = _tls(sub)
    if _collinear(ev_sub):
        raise ValueError("points are collinear (or coincident): no unique plane")

    if auto:
        if len(sub) >= 4:
            lq = sub if len(sub) <= LQS_POINTS else sub[rng.choice(len(sub), LQS_POINTS, replace=False)]
            sigma0, _ = lqs_scale(lq, rng)
        else:
            sigma0 = 0.0
        threshold = max(INLIER_K_SIGMA * sigma0, THRESHOLD_FLOOR_MM)
    else:
        threshold = threshold_mm
    normal, offset = _ransac(sub, threshold, rng)
    if auto:
        # refine from above: the truncated-scale iteration then settles on its largest
        # fixed point, and does not collapse onto a thin subset when the first scale
        # was low (as the least-quantile scale of a small cloud is)
        threshold *= REFINE_START
    normal, offset, threshold = _refine(sub, normal, offset, threshold, auto)
    selection = np.append(normal, offset)

    # the selection frame: origin o (subsample centroid), axes (e_u, e_v, normal); the
    # subsample's principal axes give e_u, e_v
    o = c_sub
    e_u = ev_vec[:, 2] - (ev_vec[:, 2] @ normal) * normal
    e_u /= np.linalg.norm(e_u)
    e_u *= 1.0 if e_u[np.argmax(np.abs(e_u))] > 0 else -1.0
    R1 = np.column_stack([e_u, np.cross(normal, e_u), normal])
    length = math.sqrt(max(ev_sub[2], 1e-300) / len(sub))  # scales u, v for conditioning

    # pass 1 (all points, chunked): select the inliers and accumulate the Gram matrix of
    # X = [1, u, v, u^2, u v, v^2, w] in the selection frame (u, v scaled by `length`):
    # it holds both the inliers' scatter (for the TLS plane) and the normal equations of
    # the quadratic form
    mask = np.empty(m, dtype=bool)
    G = np.zeros((7, 7))
    e_v = R1[:, 1]
    o_u, o_v, o_w = float(o @ e_u), float(o @ e_v), float(o @ normal)
    inv_len = 1.0 / length
    for a in range(0, m, _CHUNK):
        chunk = pts[a : a + _CHUNK]
        w = chunk @ normal  # matrix-vector products: (k, 3) @ (3, 3) is far slower in BLAS
        if not np.isfinite(w).all():
            i = a + int(np.argmax(~np.isfinite(w)))
            raise ValueError(f"point {i + 1} is {pts[i].tolist()}: coordinates must be finite (no NaN or inf)")
        sel = np.abs(w + offset) <= threshold
        mask[a : a + _CHUNK] = sel
        y = chunk[sel]
        X = np.empty((7, len(y)))  # rows: 1, u, v, u^2, u v, v^2, w
        X[0] = 1.0
        np.dot(y, e_u, out=X[1])
        X[1] -= o_u
        X[1] *= inv_len
        np.dot(y, e_v, out=X[2])
        X[2] -= o_v
        X[2] *= inv_len
        np.multiply(X[1], X[1], out=X[3])
        np.multiply(X[1], X[2], out=X[4])
        np.multiply(X[2], X[2], out=X[5])
        np.dot(y, normal, out=X[6])
        X[6] -= o_w
        G += X @ X.T
    cnt = int(round(G[0, 0]))
    if cnt < 3:
        raise ValueError(f"{cnt} point(s) within {threshold:.3g} mm of the best plane: the cloud is all outliers")

    # TLS plane from the scatter of (u, v, w) about the inliers' mean
    idx = [1, 2, 6]
    scale = np.array([length, length, 1.0])
    mean = G[0, idx] / cnt * scale
    second = G[np.ix_(idx, idx)] * np.outer(scale, scale)
    scatter = second - cnt * np.outer(mean, mean)
    evals, evecs = np.linalg.eigh(0.5 * (scatter + scatter.T))
    evals = np.clip(evals, 0.0, None)
    if _collinear(evals):
        raise ValueError(f"the {cnt} inliers are collinear (or coincident): no unique plane")
    ratio = cnt / m
    if ratio < MIN_INLIER_RATIO:
        raise ValueError(
            f"no datum plane: the best plane holds {cnt} of {m} points ({ratio:.1%}) within {threshold:.3g} mm, "
            f"need at least {MIN_INLIER_RATIO:.0%}; the cloud is all outliers (crop it, or set the threshold)"
        )
    thick, wide = math.sqrt(evals[0] / cnt), math.sqrt(evals[1] / cnt)
    if thick > MAX_THICKNESS_RATIO * wide:
        raise ValueError(
            f"no datum plane: the cloud is {thick:.3g} mm thick (RMS about its best plane) for {wide:.3g} mm wide; "
            "it is all outliers, or not a plate"
        )
    centroid = o + R1 @ mean
    vecs = R1 @ evecs  # eigenvectors in the cloud frame, ascending eigenvalues
    plane = Plane(vecs[:, 0], -float(vecs[:, 0] @ centroid))
    n_fit = plane.normal
    u_ax = vecs[:, 2] - (vecs[:, 2] @ n_fit) * n_fit  # the inliers' largest spread
    u_ax /= np.linalg.norm(u_ax)
    u_ax *= 1.0 if u_ax[np.argmax(np.abs(u_ax))] > 0 else -1.0
    axes = np.array([u_ax, np.cross(n_fit, u_ax)])

    # pass 2 (all points, one dot product each): the inliers' extreme residuals
    rmin, rmax = math.inf, -math.inf
    for a in range(0, m, _CHUNK):
        r = (pts[a : a + _CHUNK] @ n_fit + plane.offset)[mask[a : a + _CHUNK]]
        if len(r):
            rmin, rmax = min(rmin, float(r.min())), max(rmax, float(r.max()))

    rss = float(evals[0])
    dof = cnt - 3
    sigma2 = rss / dof if dof > 0 else math.nan
    # the inlier window follows the fit (points are kept within +-t of the plane being
    # fitted): for Gaussian noise that inflates the estimate's variance over the plain
    # least-squares formula by 1 / g(k)^4, k = t / sigma the window in noise sigmas and
    # g(k) the truncated normal's sd (M-estimation sandwich E[psi^2] / E[psi']^2 for
    # psi(r) = r 1{|r| <= t}; 1.056 at k = 3, -> 1 for a wide window)
    k_win = window_sigmas(threshold, math.sqrt(sigma2)) if dof > 0 else math.inf
    inflate = truncated_normal_std(k_win) ** -4 if math.isfinite(k_win) else 1.0
    cov_n = sigma2 * (np.outer(vecs[:, 2], vecs[:, 2]) / evals[2] + np.outer(vecs[:, 1], vecs[:, 1]) / evals[1])
    J = np.vstack([np.eye(3), -centroid])
    cov = J @ cov_n @ J.T
    cov[3, 3] += sigma2 / cnt
    cov *= inflate

    # residual to the final plane, r = alpha + beta u + gamma v + delta w (exact, rigid)
    n_loc = R1.T @ n_fit
    lin = np.array([float(n_fit @ o + plane.offset), n_loc[0] * length, n_loc[1] * length, n_loc[2]])
    # the final (u, v) in the selection frame: (u_sel, v_sel) = A (u, v) + b
    A = R1[:, :2].T @ axes.T
    b = mean[:2]
    form = _form(G, lin, cnt, length, (A, b), centroid, axes, sub, selection, threshold)
    return PlaneFit(
        plane=plane,
        covariance=cov,
        centroid=centroid,
        axes=axes,
        n_points=m,
        n_inliers=cnt,
        threshold=float(threshold),
        threshold_auto=auto,
        noise_sigma=float(math.sqrt(sigma2)) if dof > 0 else math.nan,
        rms=float(math.sqrt(rss / cnt)),
        residual_min=rmin,
        residual_max=rmax,
        form=form,
        seed=seed,
        ransac_points=len(sub),
        selection_plane=selection,
        window_k=float(k_win),
    )


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
    form = PlaneForm(
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


# ---------------------------------------------------------------------------------------
# files


_PLOT_SUFFIXES = {".png", ".pdf", ".svg"}
_PLOT_MAX_POINTS = 200_000


def plot_residuals(points, fit: PlaneFit, path) -> None:
    """Write a residual map over the plate (inliers coloured by residual, outliers grey).

    Parameters
    ----------
    points : (m, 3) float, mm, cloud frame
        The cloud ``fit`` was fitted to.
    fit : PlaneFit
    path : str or os.PathLike
        ``.png``, ``.pdf`` or ``.svg``; written as is (callers make it atomic).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    pts = np.asarray(points, dtype=float)
    if len(pts) > _PLOT_MAX_POINTS:  # a deterministic thinning, for the figure only
        pts = pts[np.sort(np.random.default_rng(fit.seed).choice(len(pts), _PLOT_MAX_POINTS, replace=False))]
    inl = fit.inliers(pts)
    r = fit.residuals(pts)
    uv = (pts - fit.centroid) @ fit.axes.T
    fig = Figure(figsize=(8, 6.2), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    lim = float(np.max(np.abs(r[inl]))) if inl.any() else 1.0
    ax.scatter(uv[~inl, 0], uv[~inl, 1], s=8, c="0.6", marker="x", linewidths=0.6, label=f"outliers ({fit.n_points - fit.n_inliers})")
    size = 4 if inl.sum() > 20000 else 12
    sc = ax.scatter(uv[inl, 0], uv[inl, 1], s=size, c=r[inl], cmap="RdBu_r", vmin=-lim, vmax=lim, linewidths=0)
    fig.colorbar(sc, ax=ax, label="residual to the plane (mm, + along the normal)")
    if fit.form is not None and inl.sum() >= 7:
        gu = np.linspace(uv[inl, 0].min(), uv[inl, 0].max(), 60)
        gv = np.linspace(uv[inl, 1].min(), uv[inl, 1].max(), 60)
        U, V = np.meshgrid(gu, gv)
        cs = ax.contour(U, V, fit.form.evaluate(U, V), levels=8, colors="k", linewidths=0.6, alpha=0.6)
        ax.clabel(cs, fmt="%.4f", fontsize=6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("u (mm, in-plane, from the centroid)")
    ax.set_ylabel("v (mm, in-plane)")
    form = ""
    if fit.form is not None:
        form = f", quadratic form P-V {fit.form.pv:.4f} mm (p = {fit.form.p_value:.2g})"
    ax.set_title(
        f"{Path(fit.source).name or 'cloud'}: {fit.n_inliers}/{fit.n_points} inliers, RMS {fit.rms:.4f} mm, "
        f"flatness {fit.flatness:.4f} mm{form}",
        fontsize=9,
    )
    if (~inl).any():
        ax.legend(loc="upper right", fontsize=7)
    fig.savefig(path, dpi=130)


def _check_output(path, what, suffixes=None):
    p = Path(path)
    if not p.parent.exists():
        raise ValueError(f"{path}: directory {p.parent} does not exist (for the {what})")
    if p.is_dir():
        raise ValueError(f"{path}: is a directory (for the {what})")
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise ValueError(f"{path}: the {what} must be one of {', '.join(sorted(suffixes))}")


def fit_plane_file(cloud, threshold_mm=None, seed=0, out=None, plot=None) -> PlaneFit:
    """Read a cloud, fit its datum plane, and write the JSON and the residual map.

    Parameters
    ----------
    cloud : str or os.PathLike
        Any format :func:`metrology.clouds.read_cloud` reads.
    threshold_mm, seed
        As :func:`fit_plane_robust`.
    out : str or os.PathLike or None
        JSON file (``PlaneFit.to_dict()``), readable by ``Plane.from_json``.
    plot : str or os.PathLike or None
        Residual map (``.png``, ``.pdf``, ``.svg``).

    Both outputs are written atomically and together: on any error neither exists.
    Errors are ValueError naming the file.
    """
    from metrology.io.atomic import atomic_path
    from metrology.io.clouds import cloud_format, read_cloud

    fmt = cloud_format(cloud)
    if out is not None:
        _check_output(out, "plane JSON")
    if plot is not None:
        _check_output(plot, "residual plot", _PLOT_SUFFIXES)
    points = read_cloud(cloud)
    try:
        fit = fit_plane_robust(points, threshold_mm=threshold_mm, seed=seed)
    except ValueError as exc:
        raise ValueError(f"{cloud}: {exc}") from None
    fit = replace(fit, source=str(cloud), format=fmt)
    with contextlib.ExitStack() as stack:
        if out is not None:
            tmp = stack.enter_context(atomic_path(out))
            tmp.write_text(json.dumps(fit.to_dict(), indent=2) + "\n", encoding="utf-8")
        if plot is not None:
            tmp = stack.enter_context(atomic_path(plot))
            plot_residuals(points, fit, tmp)
    return fit

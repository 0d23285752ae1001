"""The robust datum-plane fit: RANSAC for the inliers, total least squares on them, the
fit's uncertainty and the datum's form (:mod:`metrology.datum.form`).

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
3. **RANSAC** on the subsample (:func:`_ransac`, numpy, as Open3D's ``segment_plane``),
   its triples drawn from the same ``Generator``.
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

The sign convention is :class:`metrology.core.plane.Plane`'s: unit normal, ``D <= 0``.
"""

from __future__ import annotations

import math

import numpy as np

from metrology.core.plane import Plane, principal_axes
from metrology.core.tolerances import COLLINEAR_RTOL
from metrology.datum.form import fit_form
from metrology.datum.result import PlaneFit
from metrology.datum.scale import INLIER_K_SIGMA, LQS_POINTS, lqs_scale, truncated_normal_std, window_sigmas

__all__ = ["fit_plane_robust", "check_threshold", "MIN_FIT_POINTS", "MIN_FIT_INLIERS", "TooFewPoints", "NoDatumPlane"]

#: RANSAC and the threshold search run on a seeded subsample of at most this many points
RANSAC_MAX_POINTS = 20_000
#: maximum RANSAC hypotheses; RANSAC stops earlier once it has found, with probability
#: RANSAC_PROBABILITY, a hypothesis of all inliers
RANSAC_ITERATIONS = 1000
RANSAC_PROBABILITY = 0.99999999
#: fewest points of a fit: three beyond the plane's three parameters, so that a fit is redundant
#: (a plane through 3 points "fits" with residual 0 and no uncertainty at all)
MIN_FIT_POINTS = 6
#: fewest inliers of a fit: one residual degree of freedom at least, so that the noise and the
#: uncertainty are estimated (a plane through its 3 inliers has none)
MIN_FIT_INLIERS = 4
#: a fit whose inliers are less than this share of the cloud is refused (unitless)
MIN_INLIER_RATIO = 0.2
#: a fit whose inliers are thicker (RMS about the plane) than this share of their
#: smallest in-plane RMS spread is refused: the cloud is not a plate (unitless)
MAX_THICKNESS_RATIO = 0.05
#: smallest default threshold, mm (a noise-free synthetic cloud would otherwise get 0)
THRESHOLD_FLOOR_MM = 1e-6
#: refinement rounds on the subsample, at most
REFINE_MAX = 50
#: the default-threshold refinement starts at this multiple of RANSAC's threshold (unitless)
REFINE_START = 3.0
#: points per chunk in the passes over the whole cloud
_CHUNK = 1 << 17


def _collinear(evals) -> bool:
    """Scatter eigenvalues (ascending) of a collinear or coincident set (in singular values)."""
    s = np.sqrt(np.clip(evals, 0.0, None))
    return bool(s[1] <= COLLINEAR_RTOL * max(s[2], 1e-300))



#: RANSAC hypotheses scored together: the first batch this many (a clean datum stops after ~10),
#: each next one twice as many, up to RANSAC_BATCH_MAX (an (n, batch) matrix: 20 MB at 2 x 10^4 points)
RANSAC_BATCH = 16
RANSAC_BATCH_MAX = 128


def _ransac(sub, threshold, rng):
    """RANSAC plane on ``sub (n, 3) mm``: planes through random triples drawn by ``rng``,
    scored by their count of points within ``threshold`` mm, in batches; stops once a
    hypothesis of all inliers has been drawn with probability ``RANSAC_PROBABILITY``
    (at most ``RANSAC_ITERATIONS``). Returns the best plane's unit normal and offset.

    Open3D's ``segment_plane`` does the same; metro's own is numpy (no Open3D import: it
    takes longer than the whole fit of 10^6 points) and draws from the caller's generator.
    """
    n = len(sub)
    best, best_count, needed, done, batch = None, 0, RANSAC_ITERATIONS, 0, RANSAC_BATCH
    while done < needed:
        b = min(batch, needed - done)
        batch = min(2 * batch, RANSAC_BATCH_MAX)
        idx = rng.integers(0, n, (b, 3))
        p0 = sub[idx[:, 0]]
        normals = np.cross(sub[idx[:, 1]] - p0, sub[idx[:, 2]] - p0)
        norm = np.linalg.norm(normals, axis=1)
        ok = norm > 0
        done += b
        if not ok.any():
            continue
        normals = normals[ok] / norm[ok, None]
        offsets = -np.einsum("ij,ij->i", normals, p0[ok])
        counts = (np.abs(sub @ normals.T + offsets) <= threshold).sum(axis=0)
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best_count, best = int(counts[k]), (normals[k], float(offsets[k]))
            w = best_count / n
            miss = 1.0 - w**3
            if miss <= 0.0:
                needed = done
            else:
                needed = min(RANSAC_ITERATIONS, math.ceil(math.log(1.0 - RANSAC_PROBABILITY) / math.log(miss)))
    if best is None or best_count < 3:
        raise ValueError(f"RANSAC found no plane with 3 or more points within {threshold:.3g} mm: the cloud is all outliers")
    return best


def _refine(sub, normal, offset, threshold, auto):
    """Alternate inlier selection and TLS on the subsample (and, if ``auto``, the threshold).

    Returns ``(normal, offset, threshold, ran_away)``. With ``auto`` the threshold starts
    above the robust scale and settles downwards on a single plane; if it grows past its
    start instead, the band holds more than one surface (several planes, objects on the
    datum) and ``ran_away`` is True: the caller keeps the robust scale of the dominant
    plane's band rather than a threshold that swallows the scene.
    """
    g = truncated_normal_std(INLIER_K_SIGMA)
    mask = None
    # the least-quantile scale is reliable from LQS_POINTS points on; below, it runs low and
    # the threshold must be free to grow (a 20-point cloud has no second surface to run over)
    cap = threshold if len(sub) >= LQS_POINTS else math.inf
    for _ in range(REFINE_MAX):
        new = np.abs(sub @ normal + offset) <= threshold
        k = int(new.sum())
        if k < 3:
            raise ValueError(f"fewer than 3 points within {threshold:.3g} mm of the best plane: the cloud is all outliers")
        c, normal, _, _ = principal_axes(sub[new])
        offset = -float(normal @ c)
        new_t = threshold
        if auto:
            r = sub[new] @ normal + offset
            sigma = math.sqrt(float(r @ r) / max(k - 3, 1)) / g
            new_t = max(INLIER_K_SIGMA * sigma, THRESHOLD_FLOOR_MM)
            if new_t > cap:
                return normal, offset, threshold, True
        # the same inliers give the same plane and threshold: a fixed point
        settled = mask is not None and np.array_equal(new, mask)
        mask, threshold = new, new_t
        if settled:
            break
    return normal, offset, threshold, False


def check_threshold(threshold_mm):
    """``None`` or the threshold as a positive finite float, mm; raise naming a bad one."""
    if threshold_mm is None:
        return None
    t = float(threshold_mm)
    if not math.isfinite(t) or t <= 0:
        raise ValueError(f"threshold {t} mm: expected a positive distance in mm")
    return t


class TooFewPoints(ValueError):
    """Fewer points than :data:`MIN_FIT_POINTS` (a ``ValueError``; ``count`` the points given)."""

    def __init__(self, count):
        super().__init__(f"{count} point{'s' if count != 1 else ''}, need at least {MIN_FIT_POINTS} for a plane fit "
                         "with redundancy")
        self.count = count


class NoDatumPlane(ValueError):
    """No plane holds enough of the cloud, or the best one is not thin (a ``ValueError``)."""


#: on a refused automatic fit, thresholds tried below the automatic one: halving, this many times
SUGGEST_STEPS = 12
#: a suggested threshold must hold a Gaussian band: its window is at least this many noise sigmas
#: (residuals filling the window evenly, as other surfaces do, give about 1.7)
SUGGEST_WINDOW_K = 2.5


def fit_plane_robust(points, threshold_mm=None, seed=0) -> PlaneFit:
    """Fit the datum plane to a cloud with gross outliers (see :func:`_fit_plane`).

    When the automatic threshold finds no datum plane (a scene with several surfaces), the
    thresholds below it are tried, halving, and the refusal always names ``--threshold-mm``:
    with the largest threshold whose band holds Gaussian-like noise (window of at least
    ``SUGGEST_WINDOW_K`` sigmas), else with the largest that fits at all, saying that its
    residuals fill the band evenly (a scanner's depth steps, a textured surface), else
    with the range tried.
    """
    try:
        return _fit_plane(points, threshold_mm, seed)
    except NoDatumPlane as exc:
        if threshold_mm is not None or exc.args[1:] == ():
            raise
        start = exc.args[1]
        fallback = None
        for k in range(1, SUGGEST_STEPS + 1):
            t = start / 2**k
            try:
                fit = _fit_plane(points, t, seed)
            except ValueError:
                continue
            if fit.window_k >= SUGGEST_WINDOW_K:
                raise NoDatumPlane(f"{exc.args[0]}; --threshold-mm {t:.3g} fits the densest plane ({fit.n_inliers} of "
                                   f"{fit.n_points} points, noise {fit.noise_sigma:.3g} mm): pass it, or crop the cloud "
                                   "to the datum") from None
            fallback = fallback or (t, fit)
        if fallback is not None:
            t, fit = fallback
            raise NoDatumPlane(f"{exc.args[0]}; --threshold-mm {t:.3g} fits the densest plane ({fit.n_inliers} of "
                               f"{fit.n_points} points, noise {fit.noise_sigma:.3g} mm, its residuals filling the band "
                               f"evenly, {fit.window_k:.2g} sigmas wide: depth steps or texture rather than Gaussian "
                               "noise): pass it and check the residual map, or crop the cloud to the datum") from None
        raise NoDatumPlane(f"{exc.args[0]}; no --threshold-mm from {start / 2:.3g} down to "
                           f"{start / 2**SUGGEST_STEPS:.3g} mm fits a plane holding {MIN_INLIER_RATIO:.0%} of the cloud: "
                           "crop the cloud to the datum") from None


def _fit_plane(points, threshold_mm=None, seed=0) -> PlaneFit:
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
        and the RANSAC triples. Same seed and points, same result, to the bit.

    Returns
    -------
    PlaneFit

    Raises
    ------
    ValueError
        Fewer than ``MIN_FIT_POINTS`` points or ``MIN_FIT_INLIERS`` inliers, NaN/inf, collinear points, a bad threshold or seed, or no
        plane (inliers under ``MIN_INLIER_RATIO`` of the cloud, or a cloud as thick as wide).
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must be an (m, 3) array of x, y, z, got shape {pts.shape}")
    m = len(pts)
    threshold_mm = check_threshold(threshold_mm)
    if int(seed) != seed or seed < 0:
        raise ValueError(f"seed {seed}: expected a non-negative integer")
    if m < MIN_FIT_POINTS:
        raise TooFewPoints(m)
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
    c_sub, _, ev_sub, ev_vec = principal_axes(sub)
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
    lqs_threshold = threshold / REFINE_START if auto else threshold
    normal, offset, threshold, ran_away = _refine(sub, normal, offset, threshold, auto)
    if ran_away:
        # several surfaces near the datum: the dominant plane's band (its least-quantile
        # scale) sets the threshold, fixed; the refinement only re-selects the plane
        threshold = lqs_threshold
        normal, offset, threshold, _ = _refine(sub, normal, offset, threshold, False)
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
    if cnt < MIN_FIT_INLIERS:
        raise ValueError(f"{cnt} point(s) within {threshold:.3g} mm of the best plane, need at least {MIN_FIT_INLIERS}: "
                         "the cloud is all outliers")

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
        raise NoDatumPlane(
            f"no datum plane: the best plane holds {cnt} of {m} points ({ratio:.1%}) within {threshold:.3g} mm, "
            f"need at least {MIN_INLIER_RATIO:.0%}; the cloud is all outliers (crop it to the datum, or set "
            "--threshold-mm)", *([threshold] if auto else [])
        )
    thick, wide = math.sqrt(evals[0] / cnt), math.sqrt(evals[1] / cnt)
    if thick > MAX_THICKNESS_RATIO * wide:
        raise NoDatumPlane(
            f"no datum plane: the cloud is {thick:.3g} mm thick (RMS about its best plane) for {wide:.3g} mm wide; "
            "it is all outliers, or not a plate", *([threshold] if auto else [])
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
    form = fit_form(G, lin, cnt, length, (A, b), centroid, axes, sub, selection, threshold)
    return PlaneFit(
        plane=plane,
        covariance=cov,
        centroid=centroid,
        axes=axes,
        n_points=m,
        n_inliers=cnt,
        threshold=float(threshold),
        threshold_auto=auto,
        threshold_ran_away=ran_away,
        threshold_at_floor=bool(auto and threshold <= THRESHOLD_FLOOR_MM),
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


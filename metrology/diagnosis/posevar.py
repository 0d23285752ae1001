"""A rigid pose error as a random effect: what 3 sensors can tell of it (variance components).

A tracker's 6-DOF error moves the TCS rigidly at each pose. Distance sensors see its offset
along the datum normal and its two tilts (rotation about the normal and translation in the plane
are invisible): reading ``i`` of pose ``p`` changes by ``(e_p + a_p s_pi + b_p t_pi) / (N.u)``,
``(s, t)`` the spot's position on the datum from the TCS origin, over :data:`TILT_LEVER_MM`.
With 3 sensors these three values a pose take all three readings, so a fit of them leaves
nothing to test. What remains is the readings' *covariance* within a pose: without a pose error,
the residuals of one pose are independent with the stated noise; with one, they carry
``sigma_pos^2 c c^T + sigma_tilt^2 (s s^T + t t^T)`` more (``c = 1/(N.u)``): excess variance and,
except for one balanced split, correlation between the sensors of a pose.

:func:`random_pose_error` tests that excess against the stated noise (two one-sided score-type
statistics, one for the offset and one for the tilts, each an exact weighted sum of chi-squares
under the null, its tail by a saddlepoint approximation; the smaller p doubled), estimates the
two variances by moments with a cluster-robust (per-pose) covariance, and whitens the residuals
with the fitted covariance. The pose error explains the data only if the whitened residuals are
then white noise of the stated size on every sensor, uncorrelated between sensors (a pose error
is independent from pose to pose), and only if its covariance fits the residuals better than
excess variance on one sensor alone (:func:`_gain_over_one_sensor`): a structure on one sensor
(a periodic error, crosstalk, outside the catalogue) is not a rigid motion of the whole head,
but where the tests of the whitened residuals lack the power to say so, it passes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TILT_LEVER_MM", "RandomPoseError", "pose_columns", "random_pose_error", "detectable_rms", "wchisq_sf",
           "base_jacobian", "random_pose_stage", "random_pose_cause"]

#: lever (mm) of the tilts: a tilt is given as the displacement of a spot this far from the TCS origin
TILT_LEVER_MM = 50.0


def wchisq_sf(q: float, lam) -> float:
    """``P(sum_j lam_j X_j > q)``, ``X_j`` independent chi-square(1), ``lam (m,)`` >= 0
    (Lugannani-Rice saddlepoint approximation; accurate in the far tail)."""
    from scipy import optimize, stats

    lam = np.asarray(lam, float)
    lam = lam[lam > 1e-14 * max(float(np.max(lam, initial=0.0)), 1e-300)]
    if not len(lam):
        return 1.0 if q >= 0 else 0.0
    mean, var = float(lam.sum()), float(2 * np.sum(lam**2))
    if abs(q - mean) < 1e-3 * np.sqrt(var):  # the formula's limit at the mean (its skewness)
        return float(0.5 - 8 * np.sum(lam**3) / (6 * np.sqrt(2 * np.pi) * var**1.5))
    if q <= 0:
        return 1.0

    def k1(s):
        return float(np.sum(lam / (1 - 2 * s * lam))) - q

    top = 0.5 / lam.max()
    lo = -1e3 * top if q < mean else 0.0
    while q < mean and k1(lo) > 0:
        lo *= 10.0
    s = optimize.brentq(k1, lo if q < mean else 0.0, top * (1 - 1e-15) if q > mean else 0.0, xtol=1e-300,
                        rtol=1e-14, maxiter=500)
    K = float(-0.5 * np.sum(np.log1p(-2 * s * lam)))
    K2 = float(np.sum(2 * lam**2 / (1 - 2 * s * lam) ** 2))
    w = np.sign(s) * np.sqrt(max(2 * (s * q - K), 0.0))
    v = s * np.sqrt(K2)
    if abs(w) < 1e-8 or abs(v) < 1e-12:
        return float(0.5 - 8 * np.sum(lam**3) / (6 * np.sqrt(2 * np.pi) * var**1.5))
    return float(min(max(stats.norm.sf(w) + stats.norm.pdf(w) * (1 / v - 1 / w), 0.0), 1.0))


def pose_columns(ds, b):
    """``(p, n, 3)`` mm per mm: a reading's change per unit offset along the normal at the TCS
    origin and per unit tilt (mm at :data:`TILT_LEVER_MM`) about each in-plane axis through it.

    ``b`` the :class:`~metrology.diagnosis.decide.BaseAnalysis` (its covariates give the spots on
    the datum and ``1/(N.u)``; the TCS origin's place on the datum is the reported pose's)."""
    from metrology.core.plane import plane_basis

    ex, cov, lay = ds.export, b.cov, b.calibrated
    basis = plane_basis(ds.plane.normal)  # (2, 3), tracker frame
    spot_tcs = lay.zero[None] + b.d0[..., None] * lay.direction[None]  # (p, n, 3)
    spot = np.einsum("pij,pnj->pni", ex.tcs2tracker_rot, spot_tcs) + ex.tcs2tracker_trans[:, None]
    centre_st = np.nanmean((spot @ basis.T - cov.spot_st).reshape(-1, 2), axis=0)  # the datum centre's (s, t)
    tcs_st = ex.tcs2tracker_trans @ basis.T - centre_st  # (p, 2)
    rel = (cov.spot_st - tcs_st[:, None, :]) / TILT_LEVER_MM
    return np.stack([cov.inv_nu, rel[..., 0] * cov.inv_nu, rel[..., 1] * cov.inv_nu], axis=-1)


@dataclass(frozen=True)
class RandomPoseError:
    """:func:`random_pose_error`'s result.

    p_offset, p_tilt : float, the two one-sided tests of excess covariance; p : float, the
    smaller doubled; var : (2,) float, mm^2, the offset variance (along the normal, at the TCS
    origin) and the tilt variance (per in-plane axis, mm at the lever); var_cov : (2, 2), their
    cluster-robust covariance; whitened : (p, n) float, mm, the residuals whitened by the fitted
    covariance, times the stated noise (NaN where none); rms_mm, rms_se_mm : float, the pose
    error's RMS change of a reading and its standard error; p_explained : float, Bonferroni p of
    the noise tests of ``whitened`` (every sensor's chi-square both ways, whiteness, the pairs'
    correlations); n_tests : int; lr_one_sensor : float, twice the log-likelihood gain of the
    pose error's covariance over excess variance on one sensor alone, the sensor ``one_sensor``
    that comes closest (:func:`_gain_over_one_sensor`)
    """

    p_offset: float
    p_tilt: float
    p: float
    var: np.ndarray
    var_cov: np.ndarray
    whitened: np.ndarray
    rms_mm: float
    rms_se_mm: float
    p_explained: float
    n_tests: int
    lr_one_sensor: float
    one_sensor: int

    def params(self) -> dict:
        """Position and orientation sizes (1 sigma) with standard errors (delta method, at zero
        where the variance is not positive)."""
        out = {}
        for k, (name, unit, scale) in enumerate((("sigma_position_mm", "mm", 1.0),
                                                 ("sigma_tilt_rad", "rad", 1.0 / TILT_LEVER_MM))):
            v, se_v = float(self.var[k]), float(np.sqrt(max(self.var_cov[k, k], 0.0)))
            sd = np.sqrt(max(v, 0.0))
            se = se_v / (2 * sd) if sd > 0.5 * np.sqrt(se_v) else np.sqrt(se_v)
            out[name] = {"value": sd * scale, "stderr": float(se * scale), "unit": unit}
        return out


def base_jacobian(b, ds):
    """``(p, n, 5)``: the readings' derivatives by the five chart parameters at the base calibration."""
    from metrology.core.model import jacobian_tangent

    th = b.theta0
    return jacobian_tangent(ds.layout.zero + th[:, :3], ds.layout.direction, th[:, 3:], ds.obs.normal, ds.obs.offset)


def _projections(ds, b, comps, ok, A):
    """The null blocks and the pose error's blocks through the fit: ``(D, Wa, Wb, through)``, the
    first three ``(p, n, n)``, ``through(B)`` the same blocks for other columns ``B (p, n, m)``.
    ``D`` is each pose's block of ``I - H`` (``H`` the hat matrix of the whitened fit of the base
    geometry, 5 parameters a sensor, and the components ``comps``); ``Wa``, ``Wb`` the pose
    blocks of ``(I - H) K (I - H)``, ``K`` the block-diagonal covariance of a unit offset
    variance (``c c^T`` a pose) and of a unit tilt variance (``S S^T``): the fit takes up a share
    of the pose error too, which the moments must not charge to its size."""
    p, n = ok.shape
    J = base_jacobian(b, ds) / b.sigma[None, :, None]
    cols = [np.zeros((p, n, 5 * n))]
    for i in range(n):
        cols[0][:, i, 5 * i:5 * i + 5] = J[:, i]
    for c in comps:
        if c.per_pose or c.n_params == 0 or c.drops_readings:
            continue
        cols.append(c.jacobian(c.values, b.d0, b.cov) / b.sigma[None, :, None])
    X = np.where(ok[..., None], np.concatenate(cols, axis=-1), 0.0)
    G = np.linalg.pinv(X.reshape(p * n, -1).T @ X.reshape(p * n, -1), rcond=1e-12, hermitian=True)
    H = np.einsum("pik,kl,pjl->pij", X, G, X)
    D = np.where(ok[:, :, None] & ok[:, None, :], np.eye(n)[None] - H, 0.0)

    XG = X @ G  # (p, n, k): X G once (a three-operand einsum loops over every index: 4 % of a diagnosis)

    def through(B):  # B (p, n, m): each pose's columns; the pose blocks of P B B^T P
        m = B.shape[2]
        XtB = np.einsum("qnk,qnm->kqm", X, B).reshape(-1, p * m)
        PB = -(XG.reshape(p * n, -1) @ XtB).reshape(p, n, p, m)
        PB[np.arange(p), :, np.arange(p), :] += B
        return np.einsum("pnqm,pjqm->pnj", PB, PB)

    return D, through(A[..., :1]), through(A[..., 1:]), through


def _moments(z, A, D, Wa, Wb):
    """Per pose the two statistics ``u (p, 2)`` (the offset's and the tilts' squared projections),
    their null means ``m0 (p, 2)`` and their slopes in the two variances ``M (p, 2, 2)``."""
    c, S = A[..., 0], A[..., 1:]
    cz, Sz = np.einsum("pn,pn->p", c, z), np.einsum("pnk,pn->pk", S, z)
    u = np.stack([cz**2, np.sum(Sz**2, axis=1)], axis=1)

    def quad(W):
        return np.stack([np.einsum("pi,pij,pj->p", c, W, c), np.einsum("pik,pij,pjk->p", S, W, S)], axis=1)

    return u, quad(D), np.stack([quad(Wa), quad(Wb)], axis=2)


def _weights(A, V):
    """The chi-square weights of the two statistics when a pose's whitened residuals have the
    covariance ``V (p, n, n)``: ``c^T V c`` a pose, and the eigenvalues of ``S^T V S``."""
    c, S = A[..., 0], A[..., 1:]
    la = np.einsum("pi,pij,pj->p", c, V, c)
    lb = np.linalg.eigvalsh(np.einsum("pik,pij,pjl->pkl", S, V, S)).ravel()
    return la, lb


def _per_unit_variance(A_mm, ok) -> np.ndarray:
    """``(2,)``: a reading's mean square change (mm^2) per unit offset variance and per unit tilt
    variance, over the readings ``ok (p, n)``; ``A_mm (p, n, 3)`` of :func:`pose_columns`."""
    A2 = np.where(ok[..., None], A_mm, np.nan) ** 2
    return np.array([np.nanmean(A2[..., 0]), np.nanmean(A2[..., 1] + A2[..., 2])])


def random_pose_error(ds, b, fit_residual, rng: np.random.Generator, comps=(), flags=None) -> RandomPoseError:
    """Test and size a per-pose rigid error as a random effect in ``fit_residual (p, n)`` mm, the
    residuals of the base model plus ``comps`` (no pose error among them), against the stated
    noise ``b.sigma``; ``flags (p, n)`` bool readings left out (gross); ``rng`` the generator of
    the whiteness permutation test (the battery's, ``stats.battery_rng``). See the module."""
    from scipy import stats

    from metrology.diagnosis.stats import ljung_box

    sig = b.sigma
    ok = np.isfinite(fit_residual) & (True if flags is None else ~flags)
    z = np.where(ok, fit_residual / sig[None, :], 0.0)
    A_mm = pose_columns(ds, b)
    A = np.where(ok[..., None], A_mm / sig[None, :, None], 0.0)
    D, Wa, Wb, through = _projections(ds, b, comps, ok, A)
    u, m0, M = _moments(z, A, D, Wa, Wb)
    la, lb = _weights(A, D)
    p_a, p_b = wchisq_sf(float(u[:, 0].sum()), la), wchisq_sf(float(u[:, 1].sum()), lb)
    Msum = M.sum(axis=0)
    var = np.linalg.solve(Msum, (u - m0).sum(axis=0))
    g = (u - m0) - np.einsum("pkl,l->pk", M, var)
    Minv = np.linalg.inv(Msum)
    var_cov = Minv @ (g.T @ g) @ Minv.T
    vpos = np.maximum(var, 0.0)
    # whiten each pose by the fitted covariance (the stated noise through the fit plus the pose error)
    V = D + vpos[0] * Wa + vpos[1] * Wb
    y = np.full(z.shape, np.nan)
    for q in range(len(z)):
        k = np.flatnonzero(ok[q])
        if len(k):
            w, E = np.linalg.eigh(V[q][np.ix_(k, k)])
            y[q, k] = E @ ((E.T @ z[q, k]) / np.sqrt(np.maximum(w, 1e-12)))
    # the RMS change of a reading (mm) and its standard error (delta method)
    per = _per_unit_variance(A_mm, ok)
    ms = float(per @ vpos)
    rms = float(np.sqrt(ms))
    rms_se = float(np.sqrt(max(per @ var_cov @ per, 0.0)) / (2 * rms)) if rms > 0 else float(
        np.sqrt(np.sqrt(max(per @ var_cov @ per, 0.0))))
    # explained? every sensor's whitened chi-square (both ways), whiteness, the pairs' correlations
    n = z.shape[1]
    pv = []
    for i in range(n):
        yi = y[ok[:, i], i]
        c2 = float(np.sum(yi**2))
        pv.append(min(1.0, 2 * min(stats.chi2.sf(c2, len(yi)), stats.chi2.cdf(c2, len(yi)))))
        pv.append(ljung_box(yi, min(10, max(len(yi) // 5, 1)), rng))
        for j in range(i + 1, n):
            both = ok[:, i] & ok[:, j]
            if both.sum() >= 4:
                pv.append(float(stats.pearsonr(y[both, i], y[both, j]).pvalue))
    p_expl = min(1.0, min(pv) * len(pv))
    lr, rival = _gain_over_one_sensor(z, ok, D, [Wa, Wb], through)
    return RandomPoseError(p_a, p_b, min(1.0, 2 * min(p_a, p_b)), var, var_cov, y * sig[None, :], rms, rms_se, p_expl,
                           len(pv), lr, rival)


def _nll(z, ok, V):
    """Per pose, the Gaussian negative log-likelihood (less a constant) of the whitened residuals
    ``z (p, n)`` under the covariances ``V (p, n, n)``, over the readings ``ok``; a reading left
    out gets a unit variance and ``z = 0`` (the same zero term in every model), and a tiny ridge
    keeps a reading of leverage one (no residual left) from making a block singular."""
    n = z.shape[1]
    V = (np.where(ok[:, :, None] & ok[:, None, :], V, 0.0) + np.eye(n)[None] * (~ok)[:, :, None]
         + 1e-9 * np.eye(n)[None])
    logdet = np.linalg.slogdet(V)[1]
    return 0.5 * (logdet + np.einsum("pi,pi->p", z, np.linalg.solve(V, z[..., None])[..., 0]))


def _max_likelihood(z, ok, D, Ws) -> float:
    """The least total :func:`_nll` of ``D + sum_k v_k Ws[k]`` over the variances ``v >= 0``.

    Each ``Ws[k]`` is first scaled to a mean diagonal of one over the readings ``ok``, so that
    ``v_k`` is the added variance of a reading in units of its stated noise variance (the pose
    error's blocks come in mm^2, a sensor's unit column in sigma^2), and the starts (0.3, 3)
    are on the scale of the data."""
    from scipy import optimize

    Ws = np.asarray(Ws, float)
    diag = np.einsum("kpii->kpi", Ws)
    scale = np.array([np.mean(d[ok]) for d in diag])
    Ws = Ws / np.where(scale > 0, scale, 1.0)[:, None, None, None]

    def f(v):
        return float(np.sum(_nll(z, ok, D + np.einsum("k,kpij->pij", v, Ws))))

    return min(optimize.minimize(f, np.full(len(Ws), s0), method="L-BFGS-B", bounds=[(0.0, None)] * len(Ws)).fun
               for s0 in (0.3, 3.0))


def _gain_over_one_sensor(z, ok, D, W_pose, through):
    """``(lr, i)``: twice the log-likelihood gain of the pose error's within-pose covariance
    (``D + va Wa + vb Wb``, maximum likelihood) over the best excess variance on one sensor
    alone (``D + v E_i``, ``E_i`` that sensor's unit column through the fit), and that sensor.

    A rigid pose error moves every spot of a pose; crosstalk, a periodic error or any effect on
    one sensor adds variance to that sensor alone, which an offset and two tilts a pose also
    take exactly on 3 sensors. Crosstalk on one sensor of a 3-sensor head can pass every
    test of the whitened residuals while that sensor's excess alone explains the covariance as
    well as the pose error; real pose errors gain far more than the margin over it (the blind
    studies' figures are in ``benchmarks/results/diagnose_history.md``).

    A margin, not a test at a known level: the likelihood is per pose (the fit's coupling
    between poses left out), a pose error need not be Gaussian, and the two models are not
    nested. A fit that fails (not finite) counts as no gain (``-inf``): the pose error is then
    not named."""
    best = (np.inf, -1)
    lp = _max_likelihood(z, ok, D, W_pose)
    for i in range(z.shape[1]):
        E = np.zeros(ok.shape + (1,))
        E[:, i, 0] = ok[:, i]
        lr = 2.0 * (_max_likelihood(z, ok, D, [through(E)]) - lp)
        best = min(best, (lr if np.isfinite(lr) else -np.inf, i))
    return best


def detectable_rms(ds, b, alpha, power=0.95, splits=5) -> float:
    """The RMS change of a reading (mm) at which :func:`random_pose_error`'s test (at level
    ``alpha``) detects a pose error with probability ``power`` whatever its split between
    offset and tilts (the least favourable of ``splits`` splits), on these poses, at the stated
    noise. Under a pose error each statistic is again a weighted sum of chi-squares."""
    from scipy import optimize

    ok = np.isfinite(ds.obs.d)
    A_mm = pose_columns(ds, b)
    A = np.where(ok[..., None], A_mm / b.sigma[None, :, None], 0.0)
    D, Wa, Wb, _ = _projections(ds, b, (), ok, A)
    la, lb = _weights(A, D)

    def crit(lam):
        lo, hi = float(lam.sum()), float(lam.sum()) * 2 + 10 * np.sqrt(2 * np.sum(lam**2))
        while wchisq_sf(hi, lam) > alpha / 2:
            hi *= 2
        return optimize.brentq(lambda q: wchisq_sf(q, lam) - alpha / 2, lo, hi, rtol=1e-8)

    qa, qb = crit(la), crit(lb)
    per = _per_unit_variance(A_mm, ok)

    def pw(rms, share):
        va, vb = share * rms**2 / per[0], (1 - share) * rms**2 / per[1]
        wa, wb = _weights(A, D + va * Wa + vb * Wb)
        return max(wchisq_sf(qa, wa), wchisq_sf(qb, wb))

    worst = 0.0
    for share in np.linspace(0.0, 1.0, splits):
        lo, hi = 1e-6, float(np.max(b.sigma))
        while pw(hi, share) < power:
            hi *= 2
        r = optimize.brentq(lambda x: pw(x, share) - power, lo, hi, rtol=1e-4)
        worst = max(worst, r)
    return worst


#: what the random pose error's entry in ``causes`` says of its test (in place of a held-out gain)
TEST_TEXT = "within-pose covariance of the residuals against the stated noise"


def random_pose_stage(ds, b, steps, rng: np.random.Generator, joint):
    """``(RandomPoseError, the joint fit of the selected causes but a pose error)`` when the random
    pose error is significant at ``alpha_candidates`` split over the first step's candidates and
    itself; else None. With 4 sensors the rigid member is fitted pose by pose first; this is the
    fall-back where it was not named (its held-out prediction, from 3 other spots a few mm apart,
    is weak).
    ``joint(chosen)``: the joint fit of causes (:meth:`metrology.diagnosis.judge.Judge.joint_fit`)."""
    from metrology.diagnosis import rules
    from metrology.diagnosis.select import flags_of

    scored = steps[0].scored
    chosen = [s.chosen for s in steps if s.chosen is not None and not s.chosen.component.per_pose]
    f = joint(chosen) if chosen else b.fit
    r = random_pose_error(ds, b, f.residual, rng, f.components, flags_of(chosen))
    if not rules.random_pose_significant(r.p, len(scored)):
        return None
    return r, f


def random_pose_cause(r: RandomPoseError, tests, step, scored, f):
    """The ``causes`` entry of a random pose error and a CandidateResult standing for it (the
    offset member's, relabelled, with the joint fit ``f``), or None unless the whitened residuals'
    tests ``tests`` are consistent on every sensor, :attr:`RandomPoseError.p_explained` passes, and
    the pose error explains the within-pose covariance better than excess variance on one sensor
    alone (:func:`metrology.diagnosis.rules.random_pose_explains`)."""
    from dataclasses import replace

    from metrology.diagnosis import rules
    from metrology.diagnosis.results import Cause, Size

    if not rules.random_pose_explains(tests.consistent, r.p_explained, r.lr_one_sensor):
        return None
    pe = next((s for s in scored if s.component.per_pose), None)
    if pe is None:
        return None
    label = pe.cause + "@random"
    entry = {"component": pe.cause, "label": label, "cause": pe.cause, "sensors": [],
             "params": r.params(),
             "size": Size(r.rms_mm, r.rms_se_mm, "mm",
                          "RMS change of a reading by the pose error (its offset and tilts)"),
             "test": TEST_TEXT, "p_offset": r.p_offset, "p_tilt": r.p_tilt, "p_explained": r.p_explained,
             "lr_over_one_sensor": r.lr_one_sensor,
             "heldout_gain_chi2": 0.0, "p_heldout_given_others": None, "p_insample": r.p, "step": step}
    return Cause.from_description(entry), replace(pe, fit=f, label=label, p_insample=r.p)

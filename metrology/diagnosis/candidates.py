"""The candidates: covariates of a data set, the catalogue's candidate components, and how
each is scored (in-sample F-test and k-fold held-out gain)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from metrology.calibration.dataset import Dataset
from metrology.core.effects import REGISTRY, Component, Covariates, Outliers, Shift
from metrology.core.layout import SensorLayout
from metrology.core.model import readings
from metrology.diagnosis.fit import Fit, FitData, FitOptions, fit, fit_any
from metrology.diagnosis.heldout import HeldOut, beyond_span, kfold
from metrology.diagnosis.stats import paired_gain_p
from metrology.diagnosis import rules
from metrology.core.stats import robust_sigma

__all__ = ["covariates_for", "candidates_for", "flag_outliers", "flag_residuals", "Scoring", "CandidateResult",
           "score_candidate", "Reference", "flag_given_rigid", "deleted_t", "steps_beside", "without_runs", "without_tails"]


def covariates_for(ds: Dataset, layout_fit: SensorLayout, centre=None) -> Covariates:
    """Covariates of a :class:`~metrology.calibration.dataset.Dataset` at the calibrated geometry.

    ``centre`` (3,) mm tracker: the datum centre; default the centroid of the datum cloud if
    there is one, else the mean of the spots projected on the plane.
    """
    obs = ds.obs
    ex = ds.export
    R, t = ex.tcs2tracker_rot, ex.tcs2tracker_trans
    rng_mm = layout_fit.range_mm.copy()
    bad = ~np.all(np.isfinite(rng_mm), axis=1)
    if np.any(bad):  # no stated range: the readings' own span
        lo, hi = np.nanmin(ex.d, axis=0), np.nanmax(ex.d, axis=0)
        rng_mm[bad] = np.stack([lo, hi], axis=1)[bad]
    if centre is None:
        if ds.datum_points is not None:
            centre = np.mean(ds.datum_points, axis=0)
        else:
            d, _ = readings(layout_fit.zero, layout_fit.direction, obs.normal, obs.offset)
            spots = np.einsum("pij,pnj->pni", R, layout_fit.zero[None] + d[..., None] * layout_fit.direction[None]) + t[:, None]
            centre = np.nanmean(spots.reshape(-1, 3), axis=0)
    centre = np.asarray(centre, float)
    centre = centre - ds.plane.distance(centre) * ds.plane.normal
    has_t = np.all(np.isfinite(ex.time_s))
    has_T = np.all(np.isfinite(ex.temp_c))
    cov = Covariates.from_geometry(layout_fit.zero, layout_fit.direction, obs.normal, obs.offset, R, t,
                                   ds.plane.normal, centre, rng_mm, ex.time_s if has_t else None,
                                   ex.temp_c if has_T else None)
    span = np.stack([np.nanmin(ex.d, axis=0), np.nanmax(ex.d, axis=0)], axis=1)
    from dataclasses import replace

    cov = replace(cov, d_span=span)
    if ds.datum_points is None:
        return cov
    # the datum as the tracker scanned it, at the spots and over the cloud
    from metrology.core.effects import PlaneForm

    scanned = scan_points(ds, centre)
    height, (lo, hi) = PlaneForm.scan_surface(scanned, ds.plane.normal, ds.plane.offset, centre)
    from metrology.core.plane import plane_basis

    st_grid = (scanned - centre) @ plane_basis(ds.plane.normal).T
    w_grid = height(st_grid)  # where the tracker scanned
    w = height(cov.spot_st)
    # the form's size is beyond the plane: the scan's own best plane removed (the fitted plane's
    # tilt against it is the plane's business, carried as a nuisance in the fit)
    ok = np.isfinite(w_grid)
    A = np.column_stack([np.ones(int(ok.sum())), st_grid[ok]])

    def beyond_plane(h):  # a surface's heights at the scanned points less their best plane
        return h - A @ np.linalg.lstsq(A, h, rcond=None)[0]

    beyond = beyond_plane(w_grid[ok])
    hi_, lo_ = int(np.argmax(beyond)), int(np.argmin(beyond))
    ptp = float(beyond[hi_] - beyond[lo_])
    se = height.stderr(st_grid[ok][[hi_, lo_]])
    # the degree is chosen from the cloud, and a peak-to-valley follows the degree: its change at
    # the next degree joins the tracker noise's share in its standard error (a type B term)
    other = height.neighbour()
    by_degree = 0.0
    if other is not None:
        by_degree = abs(float(np.ptp(beyond_plane(other(st_grid[ok])))) - ptp)
    return replace(cov, scan_w=w, scan_ptp_mm=ptp, scan_ptp_se_mm=float(np.sqrt(se @ se + by_degree**2)))


#: at most this many passes of :func:`scan_points` (fit the surface, re-admit, refit)
SCAN_PASSES = 20
#: each pass tests points up to this fraction of the fitted points' half-widths beyond their box
SCAN_GROW = 0.1


def scan_points(ds: Dataset, centre):
    """The points of the datum cloud on the datum surface ``(m, 3)`` mm, tracker frame.

    The plane fit keeps the points within its window about the *plane* (``ds.datum_points``);
    on a datum whose form exceeds that window its highest and lowest regions fall outside it
    with the gross points, and the form measured over the rest is too small. Starting from those inliers, the smooth surface of
    :meth:`~metrology.core.effects.PlaneForm.scan_surface` is fitted and every point of the
    cloud whose distance from it is within the 1 % family-wise normal quantile of the
    surface's robust (MAD) residual scale is admitted; refitted until the set stops changing
    (at most :data:`SCAN_PASSES` passes). Gross points stay out: they are far from the surface,
    not only from the plane. Without ``ds.datum_cloud`` the inliers are returned.
    """
    from scipy import stats

    from metrology.core.effects import PlaneForm
    from metrology.core.plane import plane_basis

    cloud = ds.datum_cloud
    pts = ds.datum_points
    if cloud is None or len(cloud) == len(pts):
        return pts
    n = ds.plane.normal
    st = (cloud - centre) @ plane_basis(n).T
    w = cloud @ n + float(ds.plane.offset)
    z = float(stats.norm.isf(rules.gross_level(len(cloud))))
    keep = None
    for _ in range(SCAN_PASSES):
        height, _box = PlaneForm.scan_surface(pts, n, ds.plane.offset, centre)
        r = w - height(st, grow=SCAN_GROW)  # NaN beyond the box of the points fitted, a little widened
        r_in = (pts @ n + float(ds.plane.offset)) - height((pts - centre) @ plane_basis(n).T)
        scale = robust_sigma(r_in)
        new = np.isfinite(r) & (np.abs(r) <= z * scale)
        if keep is not None and np.array_equal(new, keep):
            break
        keep = new
        pts = cloud[keep]
    return pts


def candidates_for(layout: SensorLayout, cov: Covariates, flags=None) -> list:
    """Every catalogued candidate component for this data set (values zero), from the effect
    registry: per sensor each effect's :meth:`~metrology.core.effects.Component.candidates_for_sensor`,
    then each effect's :meth:`~metrology.core.effects.Component.candidates_for_setup`.

    ``flags`` (p, n) bool: readings flagged as gross (the ``outliers`` candidate); none if
    None or empty.
    """
    names = layout.names
    out = []
    for i in range(layout.n):
        for cls in REGISTRY.values():
            out += cls.candidates_for_sensor(i, names, cov)
    for cls in REGISTRY.values():
        out += cls.candidates_for_setup(names, cov, flags)
    return out


def flag_outliers(nominal, obs, cov, sigma, theta0):
    """Robust per-sensor fit; flag |r| / s > t with t at ``alpha_outlier`` family-wise.

    ``s`` is the larger of the stated noise and the residuals' robust (MAD) scale. Returns
    (flags (p, n) bool, p-value of the largest standardised residual).
    """
    p, n = obs.d.shape
    res = np.full((p, n), np.nan)
    for i in range(n):
        f = fit(FitData(nominal, obs, cov, sigma), (), sensors=[i], theta0=theta0, options=FitOptions(loss="soft_l1", solver="gn"))
        res[:, i] = f.residual[:, i]
    return flag_residuals(res, sigma)


def flag_residuals(residual, sigma):
    """Flag |r| / s > t in residuals ``(p, n)`` mm (``s`` per sensor the larger of the stated
    noise ``sigma (n,)`` mm and the residuals' MAD scale; ``t`` at ``alpha_outlier``
    family-wise over the readings). Returns (flags (p, n) bool, p-value of the largest)."""
    from scipy import stats

    m = int(np.isfinite(residual).sum())
    z = np.full(residual.shape, np.nan)
    for i in range(residual.shape[1]):
        r = residual[:, i]
        mad = robust_sigma(r)
        z[:, i] = r / max(sigma[i], mad)
    zmax = float(np.nanmax(np.abs(z)))
    p_max = min(1.0, m * 2 * float(stats.norm.sf(zmax)))
    t = float(stats.norm.isf(rules.gross_level(m)))
    flags = np.isfinite(z) & (np.abs(z) > t)
    return without_tails(without_runs(flags, z), z, t), p_max


def without_tails(flags, z, t):
    """``flags (p, n)`` bool less a sensor's flags that are the tails of its noise
    (:func:`~metrology.diagnosis.rules.tails_not_gross`: the rest of its readings heavier-tailed than
    a normal, every flagged reading within reach of the threshold ``t``; ``z (p, n)`` the
    standardised residuals, NaN at blanks), left to rule 21."""
    from scipy import stats

    out = flags.copy()
    for i in range(flags.shape[1]):
        f = flags[:, i]
        rest = z[np.isfinite(z[:, i]) & ~f, i]
        if not f.any() or len(rest) < 20:  # the kurtosis test's normal approximation needs 20
            continue
        p_shape = float(stats.kurtosistest(rest, alternative="greater").pvalue)
        if rules.tails_not_gross(p_shape, float(np.max(np.abs(z[f, i]))), t):
            out[:, i] = False
    return out


def without_runs(flags, z):
    """``flags (p, n)`` bool less the runs of consecutive flagged readings of one sensor, in pose
    order (blanks skipped), of one sign (``z (p, n)``, NaN at blanks) that persist
    (:func:`~metrology.diagnosis.rules.persists`): a step or a drift, left to their candidates."""
    out = flags.copy()
    for i in range(flags.shape[1]):
        rows = np.flatnonzero(np.isfinite(z[:, i]))
        sign = np.where(flags[rows, i], np.sign(z[rows, i]), 0.0)
        k = 0
        while k < len(rows):
            e = k
            while sign[k] != 0 and e + 1 < len(rows) and sign[e + 1] == sign[k]:
                e += 1
            if sign[k] != 0 and rules.persists(e - k + 1):
                out[rows[k:e + 1], i] = False
            k = e + 1
    return out


@dataclass(frozen=True)
class Scoring:
    """What every candidate of one selection is scored in (the values that travel together).

    ds : Dataset; b : the base analysis (:class:`~metrology.diagnosis.decide.BaseAnalysis`: its
    ``cov``, ``sigma``, ``theta0``, fit and held-out figures); flags : (p, n) bool, the readings
    flagged gross so far; p_out : float, the largest residual's p (the ``outliers`` candidate's
    test); folds : int, k of the k-fold by pose; n_cand : int, the candidates the in-sample
    test's level is Bonferroni-split over.
    """

    ds: Dataset
    b: "BaseAnalysis"  # metrology.diagnosis.decide's (which imports this module)
    flags: np.ndarray
    p_out: float
    folds: int
    n_cand: int


@dataclass(frozen=True)
class Reference:
    """The model a step scores candidates against: the components ``given`` (the causes chosen
    so far), their joint ``fit`` and its k-fold ``heldout`` figures."""

    given: tuple
    fit: Fit
    heldout: HeldOut


@dataclass(frozen=True)
class CandidateResult:
    """One candidate scored against the base model (:func:`score_candidate`).

    Attributes
    ----------
    component : Component, the candidate (values zero)
    fit : Fit, the base model plus the candidate on all poses
    heldout : HeldOut, its k-fold held-out figures
    chi2_pose : (p,) float, per-pose held-out chi-square of the extended model (all sensors)
    label, cause : str; sensors : list of str; n_params : int, the free parameters it adds
    p_insample : float, the F-test of the nested models (or the largest residual's test)
    p_heldout : float, one-sided paired t-test of the held-out gain on its sensors
    heldout_chi2_reduction : float, the held-out chi-square gain (all sensors, for ranking)
    heldout_rms_base_mm, heldout_rms_extended_mm, heldout_rms_ratio : float, its sensors
    heldout_normal_base_deg, heldout_normal_extended_deg : float
    significant : bool
    """

    label: str
    cause: str
    sensors: list
    n_params: int
    p_insample: float
    p_heldout: float
    heldout_chi2_reduction: float
    heldout_rms_base_mm: float
    heldout_rms_extended_mm: float
    heldout_rms_ratio: float
    heldout_normal_base_deg: float
    heldout_normal_extended_deg: float
    significant: bool
    component: Component
    fit: Fit
    heldout: HeldOut
    chi2_pose: np.ndarray

    def to_dict(self) -> dict:
        return {
            "label": self.label, "cause": self.cause, "sensors": self.sensors, "n_params": self.n_params,
            "p_insample": self.p_insample, "p_heldout": self.p_heldout,
            "heldout_chi2_reduction": self.heldout_chi2_reduction, "heldout_rms_base_mm": self.heldout_rms_base_mm,
            "heldout_rms_extended_mm": self.heldout_rms_extended_mm, "heldout_rms_ratio": self.heldout_rms_ratio,
            "heldout_normal_base_deg": self.heldout_normal_base_deg,
            "heldout_normal_extended_deg": self.heldout_normal_extended_deg, "significant": self.significant,
        }


def score_candidate(c: Component, sc: Scoring, ref: Reference, theta0, k_ref=0,
                    ho_rank: HeldOut | None = None) -> CandidateResult:
    """Score the candidate ``c`` in ``sc``: in-sample F-test of the nested models against
    ``ref.fit`` (``base``; for ``outliers`` the largest residual's own test ``sc.p_out``) and the
    k-fold held-out gain against ``ref.heldout`` (``ho_base``); significant when both pass
    (``sc.n_cand``: the Bonferroni family). ``theta0``: the geometry the fits start from (or hold).

    ``ref.given``: components already in the model (fitted jointly with ``c``; ``base`` and
    ``ho_base`` are then their fit and held-out figures); ``k_ref``: parameters of ``c`` that
    the reference ``base`` already has (the datum's tilt when form is tested beyond it);
    ``ho_rank``: the held-out figures the ranking gain ``heldout_chi2_reduction`` is taken
    against (default ``ho_base``). Form is tested beyond the tilt but ranked against the model
    without it, as every other candidate is: a gain measured from a nearer reference is smaller,
    and a datum form then lost the first step to a pose error that explained less of it.
    """
    from scipy import stats

    base, ho_base, given = ref.fit, ref.heldout, ref.given
    nominal, obs, cov, sigma = sc.ds.layout, sc.ds.obs, sc.b.cov, sc.b.sigma
    flags, p_out, folds, n_cand = sc.flags, sc.p_out, sc.folds, sc.n_cand
    names = nominal.names
    c = c.locate(base.residual, cov, sigma)  # an effect with a place in the run is put there first
    f = fit_any(FitData(nominal, obs, cov, sigma), tuple(given) + (c,), theta0)
    k = c.n_params - (c.gauge_dof if c.per_pose else len(c.constraint(c.values)[0])) - k_ref
    S = list(c.sensors) if c.sensors else list(range(nominal.n))
    k_given = sum(g.n_params * len(set(g.sensors) & set(S)) / max(len(g.sensors), 1) for g in given
                  if g.sensors and not g.per_pose)
    chi2_b = float(np.nansum((base.residual[:, S] / sigma[S]) ** 2))
    chi2_e = float(np.nansum((f.residual[:, S] / sigma[S]) ** 2))
    m_S = int(np.isfinite(obs.d[:, S]).sum())
    dof_e = int(m_S - 5 * len(S) - k - k_given)
    if isinstance(c, Outliers):
        p_in = p_out  # selection by the largest residual: its own test
    else:
        F = ((chi2_b - chi2_e) / k) / max(chi2_e / max(dof_e, 1), 1e-300)
        # Bonferroni over the positions a located candidate was chosen among
        p_in = min(1.0, float(stats.f.sf(F, k, max(dof_e, 1))) * c.searched)
    ho = kfold(FitData(nominal, obs, cov, sigma), tuple(given) + (c,), folds, theta0)
    excl = None
    if isinstance(c, Outliers) or any(isinstance(g, Outliers) for g in given):
        # gross readings are left out of the held-out comparison: those flagged, and those that
        # only this candidate's fit reveals (an effect can hide a gross reading in the scatter
        # it makes; one such reading, predicted by both models, swamps the paired test)
        excl = flags | flag_residuals(f.residual, sigma)[0]
    if c.uses_d0:
        # a characteristic is judged where its fit saw readings: a held-out reading beyond
        # every training reading of its sensor tests extrapolation (a curve with turns
        # diverges there), not whether the curve exists; left out of both sides of the test
        out_span = beyond_span(obs.d, folds)
        excl = out_span if excl is None else (excl | out_span)
    cb = ho_base.chi2_pose(sigma, exclude=excl)
    ce = ho.chi2_pose(sigma, exclude=excl)
    diff = (cb if ho_rank is None else ho_rank.chi2_pose(sigma, exclude=excl)) - ce  # all sensors: comparable between candidates (ranking)
    diff_S = ho_base.chi2_pose(sigma, S, excl) - ho.chi2_pose(sigma, S, excl)  # its sensors: the test
    p_ho = paired_gain_p(diff_S)
    rb, re_ = ho_base.rms(S, excl), ho.rms(S, excl)
    nb_, ne_ = float(np.nanmean(ho_base.normal_dev)), float(np.nanmean(ho.normal_dev))
    # against the model it is ranked against too, when that is another (ho_rank): a reference that
    # predicts badly (a datum tilt beside a rigid pose error, whose per-pose tilts it duplicates,
    # gave held-out RMS of 1e8 mm) must not make a candidate look like a gain
    rms_ref = rb if ho_rank is None else min(rb, ho_rank.rms(S, excl))
    sig = rules.significant(p_in, p_ho, n_cand, rms_ref, re_)
    return CandidateResult(c.label, c.name, [names[i] for i in c.sensors], k, p_in, p_ho, float(np.sum(diff)), rb, re_,
                           rb / re_, float(np.rad2deg(nb_)), float(np.rad2deg(ne_)), bool(sig), c, f, ho, ce)

def deleted_t(f: Fit, k: int) -> np.ndarray:
    """|gross term| / its standard error of each reading of the ``outliers`` component ``k`` of the
    joint fit ``f`` (the reading's deleted residual, externally studentised), in its cells' order."""
    out = f.components[k]
    v = np.abs(np.asarray(out.values, float))
    se = np.asarray(out.stderr if out.stderr is not None else np.full(len(v), np.nan), float)
    return np.where(se > 0, v / np.where(se > 0, se, 1.0), np.inf)


def steps_beside(step: Shift, time_h, fin, pose: int) -> list:
    """The located ``step`` re-placed with ``pose`` on either side of it (the poses with a reading
    ``fin (p,)`` in the order of ``time_h (p,)``), where ``pose`` is within one pose of where it was
    located; the placements it is not at already."""
    order = np.flatnonzero(fin)
    order = order[np.argsort(time_h[order], kind="stable")]
    rank = {int(o): r for r, o in enumerate(order)}
    if pose not in rank or step.at_pose not in rank:
        return []
    r, ra = rank[pose], rank[step.at_pose]
    if not ra - 2 <= r <= ra + 1:
        return []
    out = []
    for first_after in (r, r + 1):  # the pose after the step, then before it
        if first_after == ra or first_after < 1 or first_after >= len(order):
            continue
        lo, hi = float(time_h[order[first_after - 1]]), float(time_h[order[first_after]])
        if not hi > lo:
            continue
        out.append(replace(step, at_h=0.5 * (lo + hi), gap_h=(lo, hi), at_pose=int(order[first_after]),
                           before_pose=int(order[first_after - 1]), located_in=None, values=None, stderr=None))
    return out


def flag_given_rigid(f: Fit, cov, sigma, flags):
    """Gross readings under a rigid pose error: ``(flags (p, n) bool, p-value of the largest)``.

    An offset and two tilts a pose spread a gross reading over every sensor of its pose (with
    4 sensors a pose keeps one degree of freedom). A pose is flagged where its
    leverage-standardised residual is gross (``alpha_outlier`` family-wise over the readings,
    as :func:`~metrology.diagnosis.candidates.flag_residuals`). The reading is the one whose
    removal leaves the most plausible pose: the per-pose values solved from the other
    readings, shrunk by the spread of the fitted values over the other poses, with the least
    misfit plus prior (a gross reading read as a pose error needs a tilt far outside it).
    ``flags`` the readings already flagged (left out); those returned include them.
    """
    from scipy import stats

    rig = next(c for c in f.components if c.per_pose and c.per_pose_columns > 1)
    B = rig.pose_columns(cov)  # (p, n, m)
    e = np.asarray(rig.values, float).reshape(len(B), -1)
    ok = np.isfinite(f.residual) & ~flags
    Bw = np.where(ok[..., None], B / sigma[None, :, None], 0.0)
    h = np.einsum("pnm,pmn->pn", Bw, np.linalg.pinv(Bw, rcond=1e-10))
    ok_z = ok & (1.0 - h > 1e-3)
    z = np.where(ok_z, f.residual / sigma[None, :] / np.sqrt(np.clip(1.0 - h, 1e-6, None)), 0.0)
    m = int(ok_z.sum())
    if m == 0:
        return flags, 1.0
    z = z / max(1.0, robust_sigma(z[ok_z], about=0.0))
    zmax = float(np.max(np.abs(z)))
    p_max = min(1.0, m * 2 * float(stats.norm.sf(zmax)))
    bad = np.flatnonzero(np.max(np.abs(z), axis=1) > stats.norm.isf(rules.gross_level(m)))
    if not len(bad):
        return flags, p_max
    good = np.setdiff1d(np.arange(len(B)), bad)
    P = np.linalg.pinv(np.atleast_2d(np.cov(e[good], rowvar=False)), hermitian=True)
    y = np.where(ok, f.residual + np.einsum("pnm,pm->pn", B, e), 0.0) / sigma[None, :]  # the pose before its error
    out = flags.copy()
    for q in bad:
        score = {}
        for i in np.flatnonzero(ok[q]):
            keep = ok[q].copy()
            keep[i] = False
            A = B[q, keep] / sigma[keep, None]
            e_i = np.linalg.pinv(A.T @ A + P, hermitian=True) @ (A.T @ y[q, keep])  # a blank may leave 2
            score[i] = float(np.sum((y[q, keep] - A @ e_i) ** 2) + e_i @ P @ e_i)
        out[q, min(score, key=score.get)] = True
    return out, p_max

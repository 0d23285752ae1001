"""Several causes at once: forward selection of catalogued families with held-out validation.

Each step scores every remaining candidate *given the causes already chosen* (the base model
plus them, refitted jointly), keeps the significant ones (the same two tests as a single
cause: the in-sample F-test at ``alpha_candidates`` Bonferroni-split over the candidates, and
the one-sided held-out gain test at ``alpha_heldout``), takes the one with the largest held-out
gain, and picks the member of its family by held-out error (:func:`refine_order`). It stops
when no candidate is significant, or at ``max_causes``. The chance that a null data set gets a
cause is the chance of a false first step, which the Bonferroni split bounds; later steps are
only taken after a real cause (measured in ``benchmarks/study_blind.py``).

Families and their members (what is chosen by held-out error, never by the in-sample fit):
- the sensor characteristic: ``scale`` (the gain alone) and ``nonlinearity`` (gain, bow and
  S-shape): named ``scale`` unless the curve predicts held-out poses significantly better;
- ``drift``: linear in temperature, linear in time, the temperature with two lagged copies
  (a head that follows the air with a lag of minutes), a cubic in time (a warm-up that levels
  off, a warm-cool cycle); temperature wins a tie (the physical cause, time its proxy);
- ``plane_form``: the datum as scanned (times a gain), quadratic or cubic form, all tested
  *beyond the plane*: against the datum's tilt fitted as a nuisance parameter (a linear "form"
  is the plane fit's own uncertainty), and ranked, like every candidate, against the model
  without that tilt;
- ``pose_error``: an offset a pose along the datum normal, or (4 or more sensors) an offset and
  two tilts a pose, the visible part of a rigid 6-DOF tracker error.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from metrology.core.effects import Drift, Nonlinearity, Outliers, PlaneForm, PoseError
from metrology.diagnosis.candidates import CandidateResult, candidates_for, flag_residuals, score_candidate
from metrology.diagnosis.fit import Fit, fit_any, residual_battery
from metrology.diagnosis.heldout import HeldOut, beyond_span, kfold
from metrology.diagnosis.stats import battery_on
from metrology.diagnosis.thresholds import THRESHOLDS

__all__ = ["Step", "family_of", "refine_order", "richer_spline", "adequate_member", "forward_select", "rechoose_members", "flag_given_rigid", "p_better", "MAX_CAUSES"]

#: at most this many causes are named in one data set
MAX_CAUSES = 3
#: after the first step, a candidate on other sensors is rescored only if its first in-sample p was below this
PRUNE_P = 0.2
_GROUP = {"scale": "characteristic", "nonlinearity": "characteristic"}
#: interior knots of the characteristic's richer splines, tried in turn once a curve is chosen
#: (4: the scored member's count, with its knots at the readings' quantiles instead)
SPLINE_LADDER = (4, 8, 12)


def family_of(c) -> tuple:
    """(family group, sensors) of a candidate: members of one family on the same sensors
    compete for one place (``scale`` and ``nonlinearity`` are one family, the characteristic)."""
    return _GROUP.get(c.name, c.name), tuple(c.sensors)


def p_better(better: CandidateResult, worse: CandidateResult) -> float:
    """One-sided paired test that ``better``'s per-pose held-out chi-square is below ``worse``'s
    on ``better``'s sensors."""
    from scipy import stats

    d = worse.chi2_pose - better.chi2_pose
    return float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue) if not np.allclose(d, 0) else 1.0


def _simplicity(s: CandidateResult):
    c = s.component
    temp_first = 0 if isinstance(c, Drift) and c.variable in ("temp", "lag") else 1
    return (s.n_params, temp_first)


def refine_order(best: CandidateResult, scored) -> CandidateResult:
    """The member of ``best``'s family (same sensors) chosen by held-out error: start from the
    simplest significant member and move to a richer one (or another as rich) only when it
    predicts held-out poses significantly better (``alpha_order``) than the one held."""
    mates = sorted([s for s in scored if s.significant and family_of(s.component) == family_of(best.component)],
                   key=_simplicity)
    if not mates:
        return best
    held = mates[0]
    for other in mates[1:]:
        if other.n_params >= held.n_params and p_better(other, held) < THRESHOLDS["alpha_order"]:
            held = other
    return held


def richer_spline(ds, b, held: CandidateResult, given, ref_fit: Fit, ref_ho: HeldOut, flags, p_out, folds,
                  n_cand) -> tuple:
    """The characteristic's order, beyond the members every sensor is scored with: once a curve
    (``nonlinearity``) is chosen, splines with more knots (:data:`SPLINE_LADDER`) are scored in
    turn given the same causes, and each is taken only when it is significant and predicts
    held-out poses significantly better (``alpha_order``) than the member held (the rule of
    :func:`refine_order`). A calibration table of 6-7 knots, a shape-preserving cubic through
    them, is followed by the 4-knot spline only to ~5 um RMS (3 % of a 0.16 mm curve): enough
    to name the family, but its sensor's residuals then fail the noise tests and the cause is
    not named. Scored only after a curve is chosen, so a null data set never reaches it.

    Each rung has the splines of its knot count with knots evenly over the readings' span and
    with knots at the readings' quantiles (``@spline{k}q``, as regression splines place them by
    default): where the readings crowd in part of the span, even knots leave intervals with few
    or no readings, whose coefficients the fit cannot pin down and whose held-out predictions
    go astray (a 63-pose run: held-out RMS 1.3 times the base model's with 4 even knots, 2.5
    times smaller with 4 quantile knots). A rung's two are tested at ``alpha_order`` split
    between them, and the better of those that pass is taken.

    Returns ``(member, ladder)``: the member held, and every member of the ladder (scored
    CandidateResults of the rungs climbed, components of those not reached), for
    :func:`adequate_member`."""
    c = held.component
    if not isinstance(c, Nonlinearity) or not c.sensors:
        return held, []
    i = c.sensors[0]
    span = None if b.cov.d_span is None else tuple(float(v) for v in b.cov.d_span[i])
    d = ds.obs.d[:, i]
    d = np.sort(d[np.isfinite(d)])
    tried, rest, climbing = [], [], True
    for k in SPLINE_LADDER:
        rung = []
        if not (c.order == 0 and k <= c.knots) and k != Nonlinearity.SPLINE_KNOTS:
            rung.append(Nonlinearity((i,), names=c.names, with_gain=True, order=0, span=span, knots=k))
        inner = tuple(float(v) for v in np.quantile(d, np.arange(1, k + 1) / (k + 1)))
        # knots apart by at least a thousandth of the span (quantised or repeated readings can put
        # two quantiles on one value, and a basis function between them has no support)
        if len(d) >= 2 * (k + 4) and np.all(np.diff((d[0],) + inner + (d[-1],)) > 1e-3 * (d[-1] - d[0])):
            rung.append(Nonlinearity((i,), names=c.names, with_gain=True, order=0, span=span, knots=k, inner_mm=inner))
        if not rung:
            continue
        if not climbing:  # scored by the adequacy step only, if it is needed
            rest.append(rung)
            continue
        scored = _score_step(ds, b, rung, given, ref_fit, ref_ho, flags, p_out, folds, n_cand)
        tried.append(scored)
        # a rung's two tested at once: the order's level split between them
        better = [s for s in scored if s.significant and p_better(s, held) < THRESHOLDS["alpha_order"] / len(rung)]
        if not better:
            # a count already scored, its knots moved, is an alternative, not a richer rung
            climbing = k <= max(Nonlinearity.SPLINE_KNOTS, c.knots if c.order == 0 else 0)
            continue
        held = min(better, key=lambda s: float(np.sum(s.chi2_pose)))
        c = held.component
    return held, [s for rung in tried for s in rung] + [x for rung in rest for x in rung]


def _consistent(ds, b, cand: CandidateResult) -> bool:
    """Whether ``cand``'s fit leaves its sensors' residuals consistent with the noise (the
    verdict's battery, at ``alpha_battery``); a cause of the set-up (``pose_error``,
    ``plane_form``) acts on every sensor and is judged on all of them."""
    tests = residual_battery(cand.fit, ds.obs, b.cov, b.sigma, ds.layout.names)
    S = list(cand.component.sensors) or list(range(ds.obs.d.shape[1]))
    return battery_on(tests, S) >= THRESHOLDS["alpha_battery"]


def adequate_member(ds, b, held: CandidateResult, scored, given, ref_fit: Fit, ref_ho: HeldOut, flags, p_out,
                    folds, n_cand, more=()) -> CandidateResult:
    """The member of ``held``'s family that explains its sensors: ``held``, or where it leaves
    them inconsistent with the noise (the verdict's battery at ``alpha_battery``), the simplest
    other member that is significant, predicts held-out poses no worse (``held`` not
    significantly better, ``alpha_order``) and leaves them consistent.

    The candidates are the members of the same cause on the same sensors in ``scored`` and the
    components ``more`` (scored here, given ``given``, when reached), by number of parameters
    (ties: temperature before time, then the smaller chi-square). Only a per-sensor cause
    already chosen on its held-out gain reaches this: the family is not changed by it, and a
    null data set is affected only where a false cause was chosen already (which the verdict
    would otherwise call ``unexplained``; the null rate is measured in
    ``benchmarks/study_blind.py``). It turns a cause found "a partial explanation at best"
    into a cause named.

    Why: the held-out comparison alone cannot tell two members apart when both take most of an
    effect, yet only one may leave the sensor's residuals white. A drift that follows the air
    through a 223 s lag, 0.12 mm over a 53-minute run at 7.2 um noise: linear in temperature
    gives a held-out RMS ratio of 3.3 and leaves 10.0 um RMS on its sensor (chi-square
    p = 2e-6); the lagged member, which represents that drift to 0.4 um RMS, is not
    significantly better held out. A 0.11 mm calibration table of 4 knots at 3.5 um noise: the
    cubic and the quintic give held-out RMS ratios of 2.03 and 2.17 and leave 4.3 and 3.8 um
    RMS on the sensor (the cubic failing the battery, the quintic not)."""
    c = held.component
    if isinstance(c, Outliers) or _consistent(ds, b, held):
        return held
    mates = [s for s in scored if s.component.name == c.name and s.component.sensors == c.sensors
             and s.label != held.label]
    pending = sorted(mates + list(more), key=lambda x: x.n_params)
    seen = {held.label}
    while pending:
        k = pending[0].n_params
        group = [x for x in pending if x.n_params == k]
        pending = pending[len(group):]
        todo = [x for x in group if not isinstance(x, CandidateResult)]
        group = [x for x in group if isinstance(x, CandidateResult)]
        if todo:
            group += _score_step(ds, b, todo, given, ref_fit, ref_ho, flags, p_out, folds, n_cand)
        ok = [s for s in group if s.label not in seen and s.significant and s.n_params >= held.n_params
              and p_better(held, s) >= THRESHOLDS["alpha_order"] and _consistent(ds, b, s)]
        seen |= {s.label for s in group}
        if ok:  # temperature before time (the physical cause), then the smaller chi-square
            return min(ok, key=lambda s: (_simplicity(s), float(np.sum(s.chi2_pose))))
    return held


@dataclass(frozen=True)
class Step:
    """One step of the forward selection.

    chosen : CandidateResult, the cause added (its fit is the joint model so far)
    scored : tuple of CandidateResult, every candidate scored at this step (given the causes
        before it), largest held-out gain first
    lead : CandidateResult or None, the strongest candidate significant in sample only
    """

    chosen: CandidateResult | None
    scored: tuple
    lead: CandidateResult | None


def _score_step(ds, b, pool, given, ref_fit: Fit, ref_ho: HeldOut, flags, p_out, folds, n_cand, on_candidate=None):
    """Score every candidate of ``pool`` given the components ``given`` (their joint fit
    ``ref_fit`` and its held-out figures ``ref_ho``). Form is scored against the datum's tilt.
    ``on_candidate(i, n, label)``, if given, is called before scoring each."""
    nominal, obs = ds.layout, ds.obs
    tilt = None
    out = []
    # every fit starts from the joint model so far, and one that holds the geometry (a rigid
    # pose error, given or candidate) holds it there: the base calibration is biased by the
    # causes already found (gross readings, the pose error itself)
    th0 = ref_fit.theta if given else b.theta0
    th_offset = None
    for i, c in enumerate(pool):
        if on_candidate is not None:
            on_candidate(i, len(pool), c.label)
        ref_f, ref_h, k_ref = ref_fit, ref_ho, 0
        th_c = th0
        if isinstance(c, PoseError) and c.holds_base:
            # the rigid member holds the geometry where the offset member puts it, given the same
            # causes: the calibration without a pose error takes up part of the error's common
            # mode, which the offset member profiles out. A 0.066 mm rigid error at 3.1 um noise
            # (138 poses, 4 sensors): held at the base calibration the rigid member left 4-5 um
            # RMS and predicted held-out poses 5 times worse than the offset alone (chi-square
            # 8952 against 1792); held at the offset member's geometry it left the noise and
            # predicted them better (1241)
            if th_offset is None:
                th_offset = fit_any(nominal, obs, b.cov, b.sigma,
                                    tuple(given) + (replace(c, tilts=False, values=None, stderr=None),), th0).theta
            th_c = th_offset
        if isinstance(c, PlaneForm) and c.order != 1:
            if tilt is None:  # the datum plane's own tilt, a nuisance: form is what lies beyond it
                comps = tuple(given) + (c.nuisance(),)
                tilt = (fit_any(nominal, obs, b.cov, b.sigma, comps, th0),
                        kfold(nominal, obs, b.cov, b.sigma, comps, folds, th0))
            ref_f, ref_h, k_ref = tilt[0], tilt[1], c.nuisance().n_params
        out.append(score_candidate(c, nominal, obs, b.cov, b.sigma, ref_f, ref_h, flags, p_out, folds, th_c,
                                   n_cand, given=given, k_ref=k_ref, ho_rank=ref_ho))
    return out


def _lead(scored, n_cand):
    in_only = sorted([s for s in scored if not s.significant and s.p_insample < THRESHOLDS["alpha_candidates"] / n_cand],
                     key=lambda s: s.p_insample)
    return in_only[0] if in_only else None


def _parsimonious(sig):
    """The candidate a step takes among the significant ones ``sig`` (largest held-out gain
    first): the first, unless it is a per-pose cause and the best cause that is not per-pose
    predicts held-out poses as well (the per-pose one not significantly better, ``alpha_order``).
    An offset and two tilts a pose, as many values as readings nearly, follow any effect that
    is smooth over the few millimetres between a pose's spots: a datum form, seen by four
    spots, is locally an offset and two tilts. A fixed cause that explains as much held out
    is the explanation, the per-pose one its imitation."""
    first = sig[0]
    if not first.component.per_pose:
        return first
    fixed = next((s for s in sig if not s.component.per_pose), None)
    if fixed is not None and p_better(first, fixed) >= THRESHOLDS["alpha_order"]:
        return fixed
    return first


def forward_select(ds, b, flags, p_out, folds, max_causes=MAX_CAUSES, on_candidate=None):
    """Add causes while one gives a significant held-out gain given the others (see the module).

    ``b`` is the :class:`~metrology.diagnosis.decide.BaseAnalysis`. Returns the list of
    :class:`Step` (the last one has ``chosen`` None unless ``max_causes`` was reached).
    ``on_candidate(step, i, n, label)``, if given, is called before each candidate is scored.
    """
    pool = candidates_for(ds.layout, b.cov, flags)
    members = [c for c in pool if not isinstance(c, Outliers)]  # every member of every family
    n_cand = len(pool)
    given, steps = (), []
    ref_fit, ref_ho = b.fit, b.heldout
    while True:
        tick = None if on_candidate is None else functools.partial(on_candidate, len(steps) + 1)
        scored = _score_step(ds, b, pool, given, ref_fit, ref_ho, flags, p_out, folds, n_cand, tick)
        ranked = tuple(sorted(scored, key=lambda s: -s.heldout_chi2_reduction))
        sig = [s for s in ranked if s.significant]
        if not sig:
            steps.append(Step(None, ranked, _lead(scored, n_cand)))
            return steps
        chosen = refine_order(_parsimonious(sig), scored)
        chosen, ladder = richer_spline(ds, b, chosen, given, ref_fit, ref_ho, flags, p_out, folds, n_cand)
        chosen = adequate_member(ds, b, chosen, scored, given, ref_fit, ref_ho, flags, p_out, folds, n_cand, ladder)
        steps.append(Step(chosen, ranked, None))
        given = given + (chosen.component,)
        ref_fit, ref_ho = chosen.fit, chosen.heldout
        fam = family_of(chosen.component)
        pool = [c for c in pool if family_of(c) != fam and not (c.per_pose and chosen.component.per_pose)]
        if len(steps) == 1:
            # later steps rescore only what the first step saw at all (in-sample p < PRUNE_P), what
            # shares a sensor with a cause found (that cause inflated its F-test's scatter), and
            # the set-up's candidates: a cause on another sensor that showed nothing before stays
            # hidden after (and the steps cost a full scoring each)
            p1 = {s.label: s.p_insample for s in scored}
            near = {i for g in given for i in g.sensors}
            pool = [c for c in pool if not c.sensors or p1.get(c.label, 0.0) < PRUNE_P or set(c.sensors) & near
                    or isinstance(c, Outliers)]
        rigid = any(g.per_pose and g.per_pose_columns > 1 for g in given)
        if any(isinstance(g, Outliers) for g in given) and not isinstance(chosen.component, Outliers):
            # gross readings the new cause reveals (it hid them in its own scatter) join the
            # flagged ones, and the joint model so far is refitted with them (after a rigid pose
            # error a gross reading shows on every sensor of its pose: see flag_given_rigid)
            new = (flag_given_rigid(ref_fit, b.cov, b.sigma, flags) if rigid else flag_residuals(ref_fit.residual,
                                                                                                   b.sigma))[0]
            if np.any(new & ~flags):
                flags = flags | new
                k = next(j for j, g in enumerate(given) if isinstance(g, Outliers))
                out = replace(given[k], sensors=tuple(sorted(set(np.argwhere(flags)[:, 1].tolist()))), flags=flags,
                              values=None, stderr=None)
                given = given[:k] + (out,) + given[k + 1:]
                th0 = ref_fit.theta if rigid else b.theta0  # a held geometry is held where the joint model is
                ref_fit = fit_any(ds.layout, ds.obs, b.cov, b.sigma, given, th0)
                ref_ho = kfold(ds.layout, ds.obs, b.cov, b.sigma, given, folds, th0)
                j = [i for i, st in enumerate(steps) if st.chosen is not None and isinstance(st.chosen.component, Outliers)][0]
                steps[j] = Step(replace(steps[j].chosen, component=out, label=out.label,
                                        sensors=[ds.layout.names[i] for i in out.sensors]),
                                steps[j].scored, steps[j].lead)
                steps[-1] = Step(replace(steps[-1].chosen, fit=ref_fit, heldout=ref_ho), steps[-1].scored, None)
        elif not any(isinstance(g, Outliers) for g in given):
            # gross readings flagged anew against the causes found: a large effect makes its
            # extremes look gross to a fit without it
            flags, p_out = (flag_given_rigid(ref_fit, b.cov, b.sigma, np.zeros_like(flags)) if rigid
                            else flag_residuals(ref_fit.residual, b.sigma))
            pool = [c for c in pool if not isinstance(c, Outliers)]
            pool += Outliers.candidates_for_setup(ds.layout.names, b.cov, flags)
        if len(given) > 1:
            given, ref_fit, ref_ho = rechoose_members(ds, b, given, steps, members, flags, p_out, folds, n_cand)
        if len(given) >= max_causes or not pool:
            return steps


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
    z = z / max(1.0, 1.4826 * float(np.median(np.abs(z[ok_z]))))
    zmax = float(np.max(np.abs(z)))
    p_max = min(1.0, m * 2 * float(stats.norm.sf(zmax)))
    bad = np.flatnonzero(np.max(np.abs(z), axis=1) > stats.norm.isf(THRESHOLDS["alpha_outlier"] / (2 * m)))
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


def rechoose_members(ds, b, given, steps, members, flags, p_out, folds, n_cand):
    """Re-choose the member of each earlier cause's family given the causes chosen after it.

    A member is chosen by held-out error given the causes known at its step: a rigid pose
    error, say, is not significantly better than the offset alone while a drift is still
    unmodelled, and its orientation part then stays on every sensor. Each earlier family's
    members are scored again given every other chosen cause (the same tests, the same
    ``alpha_order`` rule of :func:`refine_order`, from the member held, then
    :func:`adequate_member` given the others). Where one changes,
    its step and the joint model are refitted (``steps`` is updated in place). Returns
    (given, joint fit, its held-out figures).
    """
    nominal, obs = ds.layout, ds.obs
    changed = False
    for j, g in enumerate(given[:-1]):
        mates = [c for c in members if family_of(c) == family_of(g)]
        if len(mates) < 2:
            continue
        others = given[:j] + given[j + 1:]
        th0 = steps[-1].chosen.fit.theta
        ref = (fit_any(nominal, obs, b.cov, b.sigma, others, th0), kfold(nominal, obs, b.cov, b.sigma, others, folds, th0))
        scored = _score_step(ds, b, mates, others, ref[0], ref[1], flags, p_out, folds, n_cand)
        held = next((s for s in scored if s.label == g.label), None)
        if held is None or not held.significant:
            continue
        new = refine_order(held, scored)
        # and the member must explain its sensors given the others (refine_order starts from the
        # simplest member: a member taken for adequacy would otherwise go back to it)
        new = adequate_member(ds, b, new, scored, others, ref[0], ref[1], flags, p_out, folds, n_cand)
        if new.label == g.label:
            continue
        given = given[:j] + (new.component,) + given[j + 1:]
        k = [i for i, st in enumerate(steps) if st.chosen is not None][j]
        th_j = b.theta0 if j == 0 else steps[k - 1].chosen.fit.theta
        f_j = fit_any(nominal, obs, b.cov, b.sigma, given[:j + 1], th_j)
        ho_j = kfold(nominal, obs, b.cov, b.sigma, given[:j + 1], folds, th_j)
        steps[k] = Step(replace(new, fit=f_j, heldout=ho_j), steps[k].scored, steps[k].lead)
        changed = True
    last = steps[-1].chosen
    if not changed:
        return given, last.fit, last.heldout
    th0 = last.fit.theta
    ref_fit = fit_any(nominal, obs, b.cov, b.sigma, given, th0)
    ref_ho = kfold(nominal, obs, b.cov, b.sigma, given, folds, th0)
    steps[-1] = Step(replace(last, fit=ref_fit, heldout=ref_ho), steps[-1].scored, None)
    return given, ref_fit, ref_ho


def drop_one_gains(ds, b, chosen, folds):
    """Held-out chi-square gain of each chosen cause given the others: the joint model without
    it against the joint model (per-pose chi-square difference over all sensors, and its
    one-sided p-value on the cause's sensors; a characteristic on the readings inside its sensor's
    training span, as it was selected). Returns a list of (gain, p)."""
    from scipy import stats

    nominal, obs = ds.layout, ds.obs
    comps = tuple(s.component for s in chosen)
    full = chosen[-1].heldout
    excl = flags_of(chosen)
    out = []
    span = beyond_span(obs.d, folds)
    for j, s in enumerate(chosen):
        rest = comps[:j] + comps[j + 1:]
        ho = kfold(nominal, obs, b.cov, b.sigma, rest, folds, b.theta0) if rest else b.heldout
        S = list(s.component.sensors) or list(range(nominal.n))
        # a characteristic is judged where its fit saw readings, as when it was selected
        # (score_candidate): a held-out reading beyond its sensor's training span tests how the
        # curve extrapolates, and one such pose swamped the paired test (a 0.16 mm table named
        # at p = 1e-17 was then "not needed", p = 0.077)
        ex = excl if not s.component.uses_d0 else (span if excl is None else excl | span)
        d_all = ho.chi2_pose(b.sigma, exclude=ex) - full.chi2_pose(b.sigma, exclude=ex)
        d_S = ho.chi2_pose(b.sigma, S, ex) - full.chi2_pose(b.sigma, S, ex)
        p = 1.0 if np.allclose(d_S, 0) else float(stats.ttest_1samp(d_S, 0.0, alternative="greater").pvalue)
        out.append((float(np.sum(d_all)), p))
    return out


def flags_of(chosen):
    """The flagged readings of a chosen ``outliers`` cause ((p, n) bool), or None."""
    from metrology.core.effects import Outliers

    for s in chosen:
        if isinstance(s.component, Outliers):
            return s.component.flags
    return None


def joint_fit(ds, b, chosen) -> Fit:
    """The chosen causes refitted jointly with the base model (``scipy.optimize.least_squares``),
    the geometry free (a rigid pose error, scored with the base geometry held, is refitted with
    it free and the directions of the geometry its per-pose values absorb held: see
    :func:`metrology.diagnosis.fit._absorbed_modes`)."""
    comps = tuple(replace(s.component, values=None, stderr=None, **({"hold": False} if isinstance(s.component, PoseError)
                                                                     else {})) for s in chosen)
    return fit_any(ds.layout, ds.obs, b.cov, b.sigma, comps, b.theta0, "lsq")

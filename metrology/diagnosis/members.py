"""The member of a family: chosen by held-out error, and one that explains its sensors.

A family (:func:`family_of`: the cause and its sensors, ``scale`` and ``nonlinearity`` one
family, the characteristic) has members of different richness: drift linear in temperature,
in time, lagged, a cubic in time; the characteristic's gain, cubic, quintic and splines; the
pose error's offset and its offset and two tilts a pose. :func:`refine_order` picks a member by
held-out error, :func:`richer_spline` climbs the characteristic's spline ladder, and
:func:`adequate_member` takes, where the member held leaves its sensors inconsistent with the
noise, the simplest one that does not. :func:`score_step` scores candidates given the causes
chosen; :mod:`metrology.diagnosis.select` runs the selection with them.
"""

from __future__ import annotations


import numpy as np

from metrology.diagnosis.candidates import CandidateResult, Reference, Scoring, score_candidate
from metrology.diagnosis.fit import FitData, fit_any, residual_battery
from metrology.diagnosis.heldout import kfold
from metrology.diagnosis.stats import battery_on, paired_gain_p
from metrology.diagnosis import rules

__all__ = ["Reference", "family_of", "p_better", "refine_order", "richer_spline", "adequate_member", "score_step"]


def family_of(c) -> tuple:
    """(family group, sensors) of a candidate: members of one family on the same sensors
    compete for one place (the registry entry's ``family``: ``scale`` and ``nonlinearity`` are one,
    the characteristic)."""
    return c.family or c.name, tuple(c.sensors)


def p_better(better: CandidateResult, worse: CandidateResult) -> float:
    """One-sided paired test that ``better``'s per-pose held-out chi-square is below ``worse``'s
    on ``better``'s sensors."""
    return paired_gain_p(worse.chi2_pose - better.chi2_pose)


def _simplicity(s: CandidateResult):
    return (s.n_params, s.component.tie_rank)


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
        if other.n_params >= held.n_params and rules.better_held_out(p_better(other, held)):
            held = other
    return held


def richer_spline(sc: Scoring, ref: Reference, held: CandidateResult) -> tuple:
    """The characteristic's order, beyond the members every sensor is scored with: once a curve
    (``nonlinearity``) is chosen, splines with more knots (its ``SPLINE_LADDER``) are scored in
    turn given the same causes, and each is taken only when it is significant and predicts
    held-out poses significantly better (``alpha_order``) than the member held (the rule of
    :func:`refine_order`): a calibration table with more knots than the scored spline is followed
    well enough to name the family but not to leave its sensor's residuals white. Scored only
    after a curve is chosen, so a null data set never reaches it.

    Each rung has the splines of its knot count with knots evenly over the readings' span and
    with knots at the readings' quantiles (``@spline{k}q``, as regression splines place them by
    default): where the readings crowd in part of the span, even knots leave intervals with few
    or no readings, whose coefficients the fit cannot pin down and whose held-out predictions
    go astray. A rung's two are tested at ``alpha_order`` split
    between them, and the better of those that pass is taken.

    Returns ``(member, ladder)``: the member held, and every member of the ladder (scored
    CandidateResults of the rungs climbed, components of those not reached), for
    :func:`adequate_member`."""
    ds, b = sc.ds, sc.b
    c = held.component
    if not hasattr(c, "richer") or not c.sensors:
        return held, []
    i = c.sensors[0]
    span = None if b.cov.d_span is None else tuple(float(v) for v in b.cov.d_span[i])
    d = ds.obs.d[:, i]
    d = np.sort(d[np.isfinite(d)])
    tried, rest, climbing = [], [], True
    for k in c.SPLINE_LADDER:
        rung = c.richer(k, d, span)
        if not rung:
            continue
        if not climbing:  # scored by the adequacy step only, if it is needed
            rest.append(rung)
            continue
        scored = score_step(sc, ref, rung)
        tried.append(scored)
        # a rung's two tested at once: the order's level split between them
        better = [s for s in scored if s.significant and rules.better_held_out(p_better(s, held), len(rung))]
        if not better:
            # a count already scored, its knots moved, is an alternative, not a richer rung
            climbing = k <= max(c.SPLINE_KNOTS, c.knots if c.order == 0 else 0)
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
    return rules.explains_sensors(battery_on(tests, S))


def adequate_member(sc: Scoring, ref: Reference, held: CandidateResult, scored, more=()) -> CandidateResult:
    """The member of ``held``'s family that explains its sensors: ``held``, or where it leaves
    them inconsistent with the noise (the verdict's battery at ``alpha_battery``), the simplest
    other member that is significant, predicts held-out poses no worse (``held`` not
    significantly better, ``alpha_order``) and leaves them consistent.

    The candidates are the members of the same cause on the same sensors in ``scored`` and the
    components ``more`` (scored here, given ``ref.given``, when reached), by number of parameters
    (ties: temperature before time, then the smaller chi-square). A cause of the set-up
    (``pose_error``, ``plane_form``) acts on every sensor and is judged on all of them, so with
    another cause not yet modelled it keeps its member here and is judged again given that
    cause (:meth:`~metrology.diagnosis.select.Selection.rechoose`). Only a cause already chosen on its held-out gain reaches
    this (never ``outliers``): the family is not changed by it, and a null data set is affected
    only where a false cause was chosen already (which the verdict would otherwise call
    ``unexplained``; the null rate is measured in ``benchmarks/study_blind.py``). It turns a
    cause found "a partial explanation at best" into a cause named.

    Why: the held-out comparison alone cannot tell two members apart when both take most of an
    effect, yet only one may leave the sensor's residuals white (the cases are in
    ``benchmarks/results/diagnose_history.md``)."""
    ds, b = sc.ds, sc.b
    c = held.component
    if c.drops_readings or _consistent(ds, b, held):
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
            group += score_step(sc, ref, todo)
        ok = [s for s in group if s.label not in seen and s.significant and s.n_params >= held.n_params
              and not rules.better_held_out(p_better(held, s)) and _consistent(ds, b, s)]
        seen |= {s.label for s in group}
        if ok:  # temperature before time (the physical cause), then the smaller chi-square
            return min(ok, key=lambda s: (_simplicity(s), float(np.sum(s.chi2_pose))))
    return held


def score_step(sc: Scoring, ref: Reference, pool, on_candidate=None):
    """Score every candidate of ``pool`` given the components ``ref.given`` (their joint fit
    ``ref.fit`` and its held-out figures ``ref.heldout``). Form is scored against the datum's tilt;
    the rigid pose error with the geometry held at the offset member's fit given the same causes.
    ``on_candidate(i, n, label)``, if given, is called before scoring each."""
    ds, b, folds = sc.ds, sc.b, sc.folds
    given, ref_fit, ref_ho = ref.given, ref.fit, ref.heldout
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
        if c.holds_base:
            # the rigid member holds the geometry where the offset member puts it, given the same
            # causes: the calibration without a pose error takes up part of the error's common
            # mode, which the offset member profiles out
            if th_offset is None:  # the offset member's fit, as scored just before if it was
                member = c.geometry_member()
                off = next((r for r in out if r.label == member.label), None)
                th_offset = off.fit.theta if off is not None else fit_any(FitData(nominal, obs, b.cov, b.sigma), tuple(given) + (member,), th0).theta
            th_c = th_offset
        nuisance = c.nuisance()
        if nuisance is not None:
            if tilt is None:  # the datum plane's own tilt, a nuisance: form is what lies beyond it
                comps = tuple(given) + (nuisance,)
                tilt = (fit_any(FitData(nominal, obs, b.cov, b.sigma), comps, th0),
                        kfold(FitData(nominal, obs, b.cov, b.sigma), comps, folds, th0))
            ref_f, ref_h, k_ref = tilt[0], tilt[1], nuisance.n_params
        out.append(score_candidate(c, sc, Reference(tuple(given), ref_f, ref_h), th_c, k_ref=k_ref, ho_rank=ref_ho))
    return out

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
  two tilts a pose, the visible part of a rigid 6-DOF tracker error; the rigid member holds the
  geometry where the offset member puts it (see :func:`metrology.diagnosis.members.score_step`).

Last, the member must explain its sensors (every sensor for a cause of the set-up):
:func:`adequate_member`. A selection that took a per-pose cause is checked against one made
without per-pose causes (:func:`_fixed_explains`). One :class:`Selection` owns the state (what
is chosen so far, the gross readings, the pool) and produces immutable :class:`Step`s; the
rules it applies are :mod:`metrology.diagnosis.rules`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from metrology.core.effects import REGISTRY, Outliers, Shift
from metrology.diagnosis.candidates import (CandidateResult, Scoring, candidates_for, deleted_t, flag_given_rigid,
                                           flag_residuals, steps_beside)
from metrology.diagnosis.heldout import Problem, beyond_span
from metrology.diagnosis.members import (Reference, adequate_member, family_of, p_better, refine_order, richer_spline,
                                         score_step)
from metrology.diagnosis.results import Decision, Reason
from metrology.diagnosis.stats import paired_gain_p
from metrology.diagnosis import rules

__all__ = ["Step", "family_of", "refine_order", "richer_spline", "adequate_member", "forward_select", "Selection", "flag_given_rigid", "p_better", "needed", "weakly_supported"]



@dataclass(frozen=True)
class Step:
    """One step of the forward selection.

    chosen : CandidateResult, the cause added (its fit is the joint model so far)
    scored : tuple of CandidateResult, every candidate scored at this step (given the causes
        before it), largest held-out gain first
    lead : CandidateResult or None, the strongest candidate significant in sample only
    reasons : tuple of Reason, the rules that fired at this step, in order
    """

    chosen: CandidateResult | None
    scored: tuple
    lead: CandidateResult | None
    reasons: tuple = ()


def _lead(scored, n_cand):
    in_only = sorted([s for s in scored if rules.in_sample_only(s, n_cand)], key=lambda s: s.p_insample)
    return in_only[0] if in_only else None


def _parsimonious(sig, why: list):
    """The candidate a step takes among the significant ones ``sig`` (largest held-out gain
    first): the first, unless it is a per-pose cause and the best cause that is not per-pose
    predicts held-out poses as well (the per-pose one not significantly better, ``alpha_order``).
    An offset and two tilts a pose, as many values as readings nearly, follow any effect that
    is smooth over the few millimetres between a pose's spots: a datum form, seen by four
    spots, is locally an offset and two tilts. A fixed cause that explains as much held out
    is the explanation, the per-pose one its imitation (a :class:`Reason` appended to ``why``)."""
    first = sig[0]
    if not first.component.per_pose:
        return first
    fixed = next((s for s in sig if not s.component.per_pose), None)
    if fixed is not None and rules.per_pose_imitates(p := p_better(first, fixed)):
        why.append(Reason(4, "per_pose_imitates", Decision.IMITATION, (first.label, fixed.label), "p_per_pose_better",
                          p, rules.ALPHA_ORDER, outcome=fixed.label))
        return fixed
    return first


def forward_select(ds, b, flags, p_out, folds, on_candidate=None) -> tuple:
    """Add causes while one gives a significant held-out gain given the others (see the module).

    ``b`` is the :class:`~metrology.diagnosis.decide.BaseAnalysis`. Returns the tuple of
    :class:`Step` (the last one has ``chosen`` None unless ``MAX_CAUSES`` were chosen).
    ``on_candidate(step, i, n, label)``, if given, is called before each candidate is scored.

    Where a per-pose cause (``pose_error``) was chosen, the selection is made again without
    per-pose causes (the first step's scores, and every candidate scored against the same
    model, reused), and that selection is taken when the per-pose one does not predict held-out
    poses significantly better (:func:`_fixed_explains`).
    """
    sel = Selection(Problem(ds, b, folds), flags, p_out, on_candidate=on_candidate)
    steps = sel.run()
    if not any(st.chosen is not None and st.chosen.component.per_pose for st in steps):
        return steps
    alt = sel.without_per_pose().run(first=steps[0].scored)
    why = []
    out = alt if _fixed_explains(b, steps, alt, flags, why) else steps
    return out[:-1] + (replace(out[-1], reasons=out[-1].reasons + tuple(why)),)


class Selection:
    """The forward selection's state (one object, its methods the steps of the procedure).

    ds : Dataset; b : BaseAnalysis; folds : int; per_pose : bool, whether per-pose causes may be
    chosen (a second selection is made without them, :func:`forward_select`); scoring : Scoring,
    what every candidate is scored in (its ``flags`` and ``p_out``, the gross readings so far);
    given : tuple of Component, the causes chosen; fit, heldout : their joint fit and k-fold
    figures (the reference of the next step); chosen : list of CandidateResult, one a step (a
    later step may revise an earlier one's member or its gross readings); ranked : list of the
    steps' scored candidates, largest held-out gain first; lead : the last step's in-sample-only
    candidate; remaining : the candidates not yet chosen from; seen : the families a later step
    rescores (:func:`_seen_after`); pool : what the next step scores; members : every member of
    every family (for :meth:`rechoose`); scores : the candidates scored so far, by the model they
    were scored against (shared with a second selection, so no candidate is scored twice
    against the same model).
    """

    def __init__(self, problem: Problem, flags, p_out, on_candidate=None):
        ds, b, folds = problem.ds, problem.b, problem.folds
        pool = candidates_for(ds.layout, b.cov, flags)
        self.problem, self.per_pose, self.on_candidate = problem, True, on_candidate
        self.ds, self.b, self.folds = ds, b, folds
        self.members = [c for c in pool if not isinstance(c, Outliers)]
        self.scoring = self.start = Scoring(ds, b, flags, p_out, folds, len(pool))
        self.pool = pool
        self.remaining, self.seen = list(self.pool), None
        self.given, self.fit, self.heldout = (), b.fit, b.heldout
        self.chosen, self.ranked, self.lead = [], [], None
        self.why = []  # per step, the rules that fired (Reason)
        self.scores = {}

    def without_per_pose(self) -> "Selection":
        """A selection from the same start that neither scores nor chooses per-pose causes (the
        per-pose candidates' count still splits the in-sample level), sharing this one's scores."""
        st = self.start
        alt = Selection(self.problem, st.flags, st.p_out, self.on_candidate)
        alt.per_pose, alt.scores = False, self.scores
        alt.pool = [c for c in alt.pool if not c.per_pose]
        alt.remaining = list(alt.pool)
        return alt

    @property
    def reference(self) -> Reference:
        """The model the next step scores candidates against."""
        return Reference(self.given, self.fit, self.heldout)

    @property
    def steps(self) -> tuple:
        """The selection so far as immutable :class:`Step`s."""
        out = [Step(c, r, None, tuple(w)) for c, r, w in zip(self.chosen, self.ranked, self.why)]
        if len(self.ranked) > len(self.chosen):
            out.append(Step(None, self.ranked[-1], self.lead, tuple(self.why[-1])))
        return tuple(out)

    def run(self, first=None) -> tuple:
        """Steps until no candidate is significant, ``MAX_CAUSES`` are chosen or nothing is left
        to score; ``first``: the first step's scored candidates, reused."""
        while True:
            scored = list(first) if first is not None and not self.ranked else self.score(self.pool)
            if not self.take(scored) or not self.pool:
                return self.steps
            if not rules.room_for_another(len(self.given)):
                self.why[-1].append(Reason(7, "room_for_another", Decision.MAX_CAUSES, tuple(s.label for s in self.chosen),
                                           "causes chosen", len(self.given), rules.MAX_CAUSES, step=len(self.ranked)))
                return self.steps

    def score(self, pool, ref: Reference | None = None) -> list:
        """Score ``pool`` against ``ref`` (default :attr:`reference`, the step's scoring, which
        ``on_candidate`` follows), each candidate once per model."""
        step, ref = ref is None, self.reference if ref is None else ref
        sc = self.scoring
        model = (tuple(g.label for g in ref.given), sc.flags.tobytes(), sc.p_out, ref.fit.theta.tobytes(),
                 ref.heldout.residual.tobytes())
        todo = [c for c in pool if (model, c.label) not in self.scores]
        tick = functools.partial(self.on_candidate, len(self.ranked) + 1) if step and self.on_candidate else None
        for c, s in zip(todo, score_step(sc, ref, todo, tick)):
            self.scores[model, c.label] = s
        return [self.scores[model, c.label] for c in pool]

    def take(self, scored) -> bool:
        """Rank a step's scored candidates and add the member chosen, if one is significant."""
        ranked = tuple(sorted(scored, key=lambda s: -s.heldout_chi2_reduction))
        self.ranked.append(ranked)
        why, k = [], len(self.ranked)
        self.why.append(why)
        sig = [s for s in ranked if s.significant and (self.per_pose or not s.component.per_pose)]
        if not sig:
            self.lead = lead = _lead(scored, self.scoring.n_cand)
            why.append(Reason(2, "significant", Decision.NOTHING_SIGNIFICANT, (), "candidates significant", 0,
                              rules.ALPHA_HELDOUT, step=k))
            if lead is not None:
                why.append(Reason(2, "in_sample_only", Decision.LEAD, (lead.label,), "p_heldout", lead.p_heldout,
                                  rules.ALPHA_HELDOUT, lead.heldout_chi2_reduction, k))
            return False
        ref = self.reference
        first = _parsimonious(sig, why)
        chosen = refine_order(first, scored)
        chosen, ladder = richer_spline(self.scoring, ref, chosen)
        chosen = adequate_member(self.scoring, ref, chosen, scored, ladder)
        # the step's choice first (the member taken, its held-out test), then what set the member
        why.insert(0, Reason(2, "significant", Decision.CHOSEN, (chosen.label,), "p_heldout", chosen.p_heldout,
                             rules.ALPHA_HELDOUT, chosen.heldout_chi2_reduction, k))
        if chosen.label != first.label:
            p = p_better(chosen, first)
            rule, name = (3, "better_held_out") if rules.better_held_out(p) else (5, "explains_sensors")
            why.append(Reason(rule, name, Decision.MEMBER, (chosen.label, first.label), "p_better", p,
                              rules.ALPHA_ORDER, chosen.heldout_chi2_reduction, k, chosen.label))
        self.add(chosen, ranked)
        return True

    def add(self, chosen, ranked):
        """The cause ``chosen`` joins the model; gross readings are flagged again, earlier members
        re-chosen given it, and the next step's pool pruned."""
        self.chosen.append(chosen)
        self.given = self.given + (chosen.component,)
        self.fit, self.heldout = chosen.fit, chosen.heldout
        fam = family_of(chosen.component)
        self.remaining = [c for c in self.remaining
                          if family_of(c) != fam and not (c.per_pose and chosen.component.per_pose)]
        self.seen = _seen_after(chosen.component, ranked, self.seen)
        self.reflag(chosen)
        if len(self.given) > 1:
            self.rechoose()
        self.pool = _prune(self.remaining, self.given, self.seen)

    def reflag(self, chosen):
        """Gross readings against the causes found. Where ``outliers`` is chosen, those the new cause
        reveals (it hid them in its own scatter) join it and the joint model is refitted (after a
        rigid pose error a gross reading shows on every sensor of its pose: :func:`flag_given_rigid`);
        where it is not, they are flagged anew (a large effect makes its extremes look gross to a
        fit without it) and the ``outliers`` candidate follows them."""
        ds, b, sc = self.ds, self.b, self.scoring
        rigid = any(g.per_pose and g.per_pose_columns > 1 for g in self.given)
        k = next((j for j, g in enumerate(self.given) if isinstance(g, Outliers)), None)
        if k is None:
            flags, p_out = (flag_given_rigid(self.fit, b.cov, b.sigma, np.zeros_like(sc.flags)) if rigid
                            else flag_residuals(self.fit.residual, b.sigma))
            self.scoring = replace(sc, flags=flags, p_out=p_out)
            self.remaining = [c for c in self.remaining if not isinstance(c, Outliers)]
            self.remaining += Outliers.candidates_for_setup(ds.layout.names, b.cov, flags)
            return
        if isinstance(chosen.component, Outliers):
            return
        new = (flag_given_rigid(self.fit, b.cov, b.sigma, sc.flags) if rigid
               else flag_residuals(self.fit.residual, b.sigma))[0]
        # the readings flagged before are judged again given the other causes, on their deleted
        # residuals (rules.gross_given_others); where none stays the cause named on them is kept
        # (judged with the others by the verdict)
        kept = self.gross_given_others(self.fit.theta if rigid else b.theta0)
        flags = (kept if kept.any() else sc.flags) | new
        if np.array_equal(flags, sc.flags):
            return
        self.scoring = replace(sc, flags=flags)
        out = replace(self.given[k], sensors=tuple(sorted(set(np.argwhere(flags)[:, 1].tolist()))), flags=flags,
                      values=None, stderr=None)
        self.given = self.given[:k] + (out,) + self.given[k + 1:]
        th0 = self.fit.theta if rigid else b.theta0  # a held geometry is held where the joint model is
        self.fit, self.heldout = self.problem.refit(self.given, th0)
        self.chosen[k] = replace(self.chosen[k], component=out, label=out.label,
                                 sensors=[ds.layout.names[i] for i in out.sensors])
        self.chosen[-1] = replace(self.chosen[-1], fit=self.fit, heldout=self.heldout)

    def gross_given_others(self, theta0):
        """The readings flagged gross ``(p, n)`` bool that stay gross given the other causes chosen
        (:func:`~metrology.diagnosis.rules.gross_given_others`): the joint fit's gross term of each
        (the reading left out, the others fitted on the rest) over its standard error; for a reading
        of a knocked sensor next to its located step, the step is also re-placed with the reading's
        pose on either side and the smaller taken."""
        ds, b, flags = self.ds, self.b, self.scoring.flags
        k = next(j for j, g in enumerate(self.given) if isinstance(g, Outliers))
        m = int(np.isfinite(ds.obs.d).sum())
        t = deleted_t(self.fit, k)
        cells = self.fit.components[k].cells  # the fit holds the chosen causes in their order
        for j, g in enumerate(self.given):
            if not isinstance(g, Shift) or g.at_pose < 0:
                continue
            for q, (pp, i) in enumerate(cells):
                if i not in g.sensors or not rules.gross_given_others(t[q], m):
                    continue
                for moved in steps_beside(g, np.asarray(b.cov.time_h, float), np.isfinite(ds.obs.d[:, i]), int(pp)):
                    f = self.problem.fit(self.given[:j] + (moved,) + self.given[j + 1:], theta0)
                    t[q] = min(t[q], deleted_t(f, k)[q])
        keep = np.array([rules.gross_given_others(v, m) for v in t], bool)
        out = np.zeros_like(flags)
        out[cells[keep, 0], cells[keep, 1]] = True
        return out

    def rechoose(self):
        """Re-choose the member of each earlier cause's family given the causes chosen after it.

        A member is chosen by held-out error given the causes known at its step: a rigid pose
        error, say, is not significantly better than the offset alone while a drift is still
        unmodelled, and its orientation part then stays on every sensor. Each earlier family's
        members are scored again given every other chosen cause (the same tests, the rule of
        :func:`refine_order` from the member held, then :func:`adequate_member` given the others).
        Where one changes, its step and the joint model are refitted."""
        b, pr = self.b, self.problem
        changed = False
        for j, g in enumerate(self.given[:-1]):
            mates = [c for c in self.members if family_of(c) == family_of(g)]
            if len(mates) < 2:
                continue
            others = self.given[:j] + self.given[j + 1:]
            th0 = self.chosen[-1].fit.theta
            ref = Reference(others, *pr.refit(others, th0))
            scored = self.score(mates, ref)
            held = next((s for s in scored if s.label == g.label), None)
            if held is None or not held.significant:
                continue
            new = refine_order(held, scored)
            # and the member must explain its sensors given the others (refine_order starts from the
            # simplest member: a member taken for adequacy would otherwise go back to it)
            new = adequate_member(self.scoring, ref, new, scored)
            if new.label == g.label:
                continue
            self.given = self.given[:j] + (new.component,) + self.given[j + 1:]
            th_j = b.theta0 if j == 0 else self.chosen[j - 1].fit.theta
            fit_j, heldout_j = pr.refit(self.given[:j + 1], th_j)
            self.chosen[j] = replace(new, fit=fit_j, heldout=heldout_j)
            changed = True
        last = self.chosen[-1]
        if not changed:
            self.fit, self.heldout = last.fit, last.heldout
            return
        self.fit, self.heldout = pr.refit(self.given, last.fit.theta)
        self.chosen[-1] = replace(last, fit=self.fit, heldout=self.heldout)


def _fixed_explains(b, steps, fixed, flags=None, why: list | None = None) -> bool:
    """Whether the causes of ``fixed`` (a selection without per-pose causes) predict held-out
    poses as well as those of ``steps`` (one with a per-pose cause): the latter's joint model
    not significantly better (``alpha_order``, the paired test of :func:`p_better` on every
    sensor). Poses with a gross reading are left out whole (``flags``, those of either
    selection, and those either joint fit shows): a per-pose model predicts each held-out
    reading from the pose's other readings, so one gross reading spoils its whole pose. Where
    the fixed causes are all among the per-pose selection's, the per-pose cause was added to
    them on its own held-out test, and it stays.

    The rule of :func:`_parsimonious`, over the whole selection instead of one step. An offset
    and two tilts a pose take three quarters of any effect on one sensor of a 4-sensor head,
    so where two sensors drift each on its own, the per-pose cause predicts held-out poses
    better than either drift alone and takes the first step; the drifts of both sensors, two
    values, explain it all (the case that motivated the rule is in
    ``benchmarks/results/diagnose_history.md``). The rule's :class:`Reason` is appended to ``why``."""
    main = [st.chosen for st in steps if st.chosen is not None]
    alt = [st.chosen for st in fixed if st.chosen is not None]
    if not alt or {s.label for s in alt} <= {s.label for s in main}:
        return False
    m, a = main[-1], alt[-1]
    gross = [f for f in (flags, flags_of(main), flags_of(alt)) if f is not None]
    gross += [flag_residuals(x.fit.residual, b.sigma)[0] for x in (m, a)]
    keep = ~np.any(np.logical_or.reduce(gross), axis=1)
    d = (a.heldout.chi2_pose(b.sigma) - m.heldout.chi2_pose(b.sigma))[keep]
    if len(d) < rules.MIN_POSES_COMPARED:
        return False
    p = paired_gain_p(d)
    taken = rules.fixed_explains_as_well(p, len(d))
    (why if why is not None else []).append(Reason(8, "fixed_explains_as_well", Decision.FIXED_SELECTION if taken else Decision.PER_POSE_SELECTION,
                      (m.label, a.label), "p_per_pose_better", p, rules.ALPHA_ORDER, float(np.sum(d)),
                      outcome=a.label if taken else m.label))
    return taken


def _seen_after(chosen, scored, seen):
    """The families a later step rescores for what the scores showed, after the step that chose
    the component ``chosen`` from ``scored``: ``None`` (rescore every family) or a set of
    :func:`family_of` keys, those with a member of in-sample p below ``PRUNE_P``.

    A family stays whole: where one member showed something, its richer members are scored
    too (a warm-up that a line in time barely shows needs its curve to be chosen). The set is
    taken once, at the first step that chose a cause on its own sensors, and kept. A set-up
    cause (datum form, pose error: no sensors of its own) inflates every sensor's scatter: after
    one, the set is dropped and the next step rescores every family: under a large form a
    drift's members can all show nothing at step 1, and pruned there the drift would never be
    scored given the form."""
    if not chosen.sensors:
        return None
    if seen is not None:
        return seen
    return {family_of(s.component) for s in scored if rules.shows_something(s.p_insample)}


def _prune(remaining, given, seen) -> list:
    """The candidates of ``remaining`` the next step scores, given the components found
    (``given``) and the families the scores showed (``seen``, from :func:`_seen_after`; None:
    all of them). Kept: the set-up's candidates, gross readings, every member of a family seen,
    and whatever shares a sensor with a cause found (that cause inflated its F-test's scatter).
    A cause on another sensor that showed nothing stays hidden after, and each step is a full
    scoring."""
    if seen is None:
        return list(remaining)
    near = {i for g in given for i in g.sensors}
    return [c for c in remaining if not c.sensors or isinstance(c, Outliers) or family_of(c) in seen
            or set(c.sensors) & near]


def drop_one_gains(problem: Problem, chosen):
    """Held-out chi-square gain of each chosen cause given the others: the joint model without
    it against the joint model (per-pose chi-square difference over all sensors, and its
    one-sided p-value on the cause's sensors; a characteristic on the readings inside its sensor's
    training span, as it was selected). Returns a list of (gain, p)."""
    b, obs, folds = problem.b, problem.ds.obs, problem.folds
    comps = tuple(s.component for s in chosen)
    full, full_theta = chosen[-1].heldout, chosen[-1].fit.theta
    excl = flags_of(chosen)
    out = []
    span = beyond_span(obs.d, folds)
    for j, s in enumerate(chosen):
        rest = comps[:j] + comps[j + 1:]
        # a rigid pose error holds the geometry: where the selection held it (the offset member's
        # fit, :func:`~metrology.diagnosis.members.score_step`), not at the base calibration, which
        # the pose error itself biases (held there, a cause looked needed that was not)
        th = full_theta if any(c.holds_base for c in rest) else b.theta0
        ho = problem.heldout(rest, th) if rest else b.heldout
        S = list(s.component.sensors) or list(range(problem.ds.layout.n))
        # a characteristic is judged where its fit saw readings, as when it was selected
        # (score_candidate): a held-out reading beyond its sensor's training span tests how the
        # curve extrapolates, and one such pose swamps the paired test
        ex = excl if not s.component.uses_d0 else (span if excl is None else excl | span)
        d_all = ho.chi2_pose(b.sigma, exclude=ex) - full.chi2_pose(b.sigma, exclude=ex)
        d_S = ho.chi2_pose(b.sigma, S, ex) - full.chi2_pose(b.sigma, S, ex)
        out.append((float(np.sum(d_all)), paired_gain_p(d_S)))
    return out


def needed(chosen, gains) -> list:
    """Per chosen cause, whether it is still needed given the others: its held-out gain given
    the others (``gains`` of :func:`drop_one_gains`; a sole cause's is against the base model)
    significant at ``alpha_heldout`` Bonferroni-split over the causes chosen. The selection's
    later steps test at ``alpha_heldout`` each, a member re-chosen or a cause added after can
    make an earlier one redundant, and a step can have tested its cause against another
    reference (a datum form beyond the plane's tilt). ``outliers`` are exempt: a flagged
    reading predicts nothing held out."""
    return [rules.needed_given_others(g[1], len(chosen), s.component.drops_readings) for s, g in zip(chosen, gains)]


def weakly_supported(causes) -> list:
    """The labels of the named causes (the verdict's ``causes`` entries) whose held-out p given
    the others is not below ``alpha_high`` (a NaN p included): named (below ``alpha_heldout``
    split over the causes, :func:`needed`), but on evidence that a null data set gives often
    enough for ``confidence: high`` to overclaim. ``outliers`` (a flagged reading
    predicts nothing held out) and a random pose error (no held-out p) are exempt."""
    return [c.label for c in causes if not REGISTRY[c.cause].drops_readings and c.p_heldout_given_others is not None
            and rules.weak_evidence(c.p_heldout_given_others)]


def flags_of(chosen):
    """The flagged readings of a chosen ``outliers`` cause ((p, n) bool), or None."""
    for s in chosen:
        if isinstance(s.component, Outliers):
            return s.component.flags
    return None

"""Steps 3-4 of the diagnosis: the verdict on the causes the selection chose.

:func:`verdict` reads top to bottom in :class:`Judge`: the causes chosen are refitted jointly
(:meth:`Judge.joint_fit`); a sole cause not needed against the base model is turned down; each
cause is kept where it is needed given the others and leaves its sensors' residuals consistent
with the noise (:func:`_judged_sensors`), and where crosstalk does not predict better; each kept
cause is described with its size, its held-out gain given the others and what the data cannot
separate; the confidence follows (:func:`metrology.diagnosis.rules.confidence_of`). Where
structure remains and no rigid pose error could be fitted (3 sensors), the same judgement is
made once more with the pose error as a random effect (:meth:`Judge.with_random_pose`), reusing
every fit the first made. The rules are in :mod:`metrology.diagnosis.rules`; each one that
fires appends its :class:`~metrology.diagnosis.results.Reason` to the judgement's trail, after
the selection's (the summary and ``metro diagnose --explain`` are made from it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from metrology.diagnosis import rules
from metrology.diagnosis.candidates import CandidateResult
from metrology.diagnosis.crosstalk import CrosstalkCheck, crosstalk_check
from metrology.diagnosis.extension import describe_named, size_of, with_model_spread
from metrology.diagnosis.fit import Fit, FitData, fit_any, residual_battery
from metrology.diagnosis.results import Cause, Confidence, Confounding, Decision, Outcome, Reason, Rival
from metrology.diagnosis.heldout import Problem
from metrology.diagnosis.select import drop_one_gains, family_of, needed, p_better, weakly_supported
from metrology.diagnosis.stats import Battery, NoiseTests, battery_on, battery_rng, noise_tests
from metrology.diagnosis.thresholds import ADVICE

__all__ = ["Judgement", "Judge", "judge"]


@dataclass(frozen=True, kw_only=True)
class Judgement:
    """Steps 3-4 (the diagnosis' judgement of the causes chosen; ``metrology.core.verdict.Verdict``
    is a command's pass/fail): the first cause (a catalogue name, or :class:`Outcome` ``none`` or
    ``unexplained``), its sensors and :class:`Confidence`, the first named candidate (its
    ``fit`` the joint model of every cause, refitted by ``lsq``; or None), the noise tests after
    the extension, the confounding notes, the first cause's description, every named cause's
    description (largest held-out gain given the others first), the lead (a candidate
    significant in sample only, when the selection stopped) and ``dropped``: the Reason (rule 10,
    ``dropped``) of a sole cause the selection chose that is not needed against the base model
    (its label, its held-out chi-square gain and p against the base model), so not named; ``rivals``:
    the Rival explanations outside the catalogue said beside the causes; ``random_pose``: the
    pose error is named as a random effect (:mod:`metrology.diagnosis.posevar`); ``reasons``: the
    trail, every :class:`Reason` in the order its rule fired (the selection's, then the verdict's).
    Built by keyword only."""

    cause: str
    confidence: Confidence
    sensors: list = field(default_factory=list)
    best: CandidateResult | None = None
    tests_extended: NoiseTests | None = None
    confounding: list[Confounding] = field(default_factory=list)
    named: Cause | None = None
    causes: tuple = ()
    lead: CandidateResult | None = None
    dropped: Reason | None = None
    rivals: tuple = ()
    random_pose: bool = False
    reasons: tuple = ()

    @property
    def outcome(self) -> Outcome:
        """A cause named, or none, or unexplained."""
        return Outcome(self.cause) if self.cause in (Outcome.NONE, Outcome.UNEXPLAINED) else Outcome.NAMED


def judge(problem: Problem, steps, rng) -> Judgement:
    """Steps 3-4 (see the module): ``problem`` the data set, base model and folds, ``steps`` the
    selection's Steps, ``rng`` the generator of the pose error's bootstrap."""
    return Judge(problem, steps, rng).judgement()


class Judge:
    """The verdict's state: the data set, the base analysis, the selection's steps, and what is
    computed once and read by both judgements (with and without a random pose error): the joint
    fits, the drop-one gains, the crosstalk checks and the causes' descriptions, by the causes
    they are of."""

    def __init__(self, problem: Problem, steps, rng):
        self.problem, self.steps, self.rng = problem, steps, rng
        self.ds, self.b, self.folds = problem.ds, problem.b, problem.folds
        self.chosen = [st.chosen for st in steps if st.chosen is not None]
        self.lead = steps[-1].lead
        self.n = self.ds.obs.d.shape[1]
        #: the selection's trail (each step's rules), which every judgement continues
        self.selected = tuple(r for st in steps for r in st.reasons)
        self._fits, self._gains, self._xtalk, self._described = {}, {}, {}, {}

    def judgement(self) -> Judgement:
        """The judgement of the causes chosen, or, where it leaves structure and a random pose
        error explains it, the judgement with that pose error."""
        from metrology.diagnosis.posevar import random_pose_stage

        v = self.fixed()
        if not rules.random_pose_tried(v.cause, v.confidence):
            return v
        rpe = random_pose_stage(self.ds, self.b, self.steps, battery_rng(), self.joint_fit)
        if rpe is None:
            return v
        # a sole cause turned down as not needed stays turned down beside the random pose error
        v2 = self.with_random_pose(*rpe, exempt_sole=v.dropped is None)
        return v if v2 is None else v2

    # -- what both judgements read, computed once ---------------------------------------------
    def joint_fit(self, chosen) -> Fit:
        """The causes ``chosen`` refitted jointly with the base model (``scipy.optimize.least_squares``),
        the geometry free (a rigid pose error, scored with the base geometry held, is refitted with
        it free and the directions of the geometry its per-pose values absorb held: see
        :func:`metrology.calibration.engine._absorbed_modes`)."""
        key = tuple(s.label for s in chosen)
        if key not in self._fits:
            comps, ds, b = tuple(s.component.for_joint_fit() for s in chosen), self.ds, self.b
            self._fits[key] = fit_any(FitData(ds.layout, ds.obs, b.cov, b.sigma), comps, b.theta0, "lsq")
        return self._fits[key]

    def gains(self, chosen) -> list:
        """Each cause's held-out gain and p given the others (:func:`drop_one_gains`)."""
        key = tuple(s.label for s in chosen)
        if key not in self._gains:
            self._gains[key] = drop_one_gains(self.problem, chosen) if chosen else []
        return self._gains[key]

    def crosstalk(self, chosen, j) -> CrosstalkCheck:
        """The crosstalk check of cause ``j`` given the causes before it."""
        key = (tuple(s.label for s in chosen[:j + 1]))
        if key not in self._xtalk:
            self._xtalk[key] = crosstalk_check(self.ds, self.b, tuple(s.component for s in chosen[:j]), chosen[j],
                                               self.folds)
        return self._xtalk[key]

    def described(self, chosen, f: Fit, j, gains) -> Cause:
        """Cause ``j`` of the joint fit ``f`` of ``chosen``: its parameters, size and held-out figures
        (no rivals: :meth:`named` adds them)."""
        key = (tuple(s.label for s in chosen), j)
        if key not in self._described:
            b, s = self.b, chosen[j]
            # the step that chose it (``chosen`` can leave a per-pose cause of an earlier step out)
            k = next((i for i, st in enumerate(self.steps) if st.chosen is not None and st.chosen.label == s.label), j)
            d = describe_named(f, self.problem, self.rng, which=j, theta_ref=b.theta0)
            size = with_model_spread(size_of(f, j, b.cov, b.d0), s, self.steps[k].scored, b.cov, b.d0)
            d.update({"cause": s.cause, "sensors": s.sensors, "size": size,
                      "heldout_gain_chi2": gains[j][0], "p_heldout_given_others": gains[j][1],
                      "p_insample": s.p_insample, "step": k + 1})
            self._described[key] = Cause.from_description(d)
        return self._described[key]

    # -- the two judgements -----------------------------------------------------------------------
    def fixed(self) -> Judgement:
        """The causes chosen, each a fixed effect: none chosen, a sole cause not needed, or
        :meth:`named`."""
        b, chosen = self.b, self.chosen
        nothing = Outcome.NONE if b.tests.consistent else Outcome.UNEXPLAINED
        if not chosen:
            confidence = rules.confidence_of_nothing(b.tests.consistent, self.lead is not None)
            why = self.selected + (Reason(16, "confidence_of_nothing", Decision.CONFIDENCE, (), "p_battery_base",
                                          b.tests.p_bonferroni, rules.ALPHA_BATTERY, outcome=confidence),)
            return Judgement(cause=nothing, confidence=confidence, lead=self.lead, reasons=why)
        f = self.joint_fit(chosen)
        tests = residual_battery(f, self.ds.obs, b.cov, b.sigma, self.ds.layout.names)
        gains = self.gains(chosen)
        need = needed(chosen, gains)
        if len(chosen) == 1 and not need[0]:
            # a sole cause whose held-out gain against the base model is not significant: not named
            dropped = Reason(10, "needed_given_others", Decision.DROPPED, (chosen[0].label,), "p_heldout_against_base",
                             gains[0][1], rules.ALPHA_HELDOUT, gains[0][0], step=1, outcome=Confidence.LOW)
            return Judgement(cause=nothing, confidence=Confidence.LOW, lead=self.lead, dropped=dropped,
                             reasons=self.selected + (dropped,))
        return self.named(chosen, f, tests, gains, sole_exempt=False)

    def with_random_pose(self, r, f: Fit, exempt_sole: bool) -> Judgement | None:
        """The fixed causes but a pose error beside the pose error as a random effect ``r`` (a
        RandomPoseError; ``f`` the fixed causes' joint fit), the residuals judged whitened by it; a
        sole fixed cause keeps its step's test (its drop-one gain is taken without the random
        effect) where ``exempt_sole``. None where the pose error does not explain the data."""
        chosen = [s for s in self.chosen if not s.component.per_pose]
        # the residuals whitened by the fitted pose error's covariance (the fit has no rigid one);
        # a pose error need not be Gaussian: no normality test
        w = r.whitened
        tests = noise_tests(w, self.b.sigma, np.isfinite(w).sum(axis=0) - 5.0, self.ds.layout.names,
                            rng=battery_rng(),
                            battery=Battery(pairs=not any(c.per_pose for c in f.components), normality=False))
        gains = self.gains(chosen)
        return self.named(chosen, f, tests, gains, sole_exempt=len(chosen) == 1 and exempt_sole, random_pose=r)

    def named(self, chosen, f: Fit, tests_ext: NoiseTests, gains, sole_exempt, random_pose=None) -> Judgement | None:
        """Keep each cause needed and judged consistent on its sensors, and not crosstalk; describe
        those kept; the confounding and the confidence, each rule's Reason appended to the trail.
        None where a random pose error is not named."""
        n, need = self.n, needed(chosen, gains)
        why = list(self.selected)
        _needed_reasons(chosen, gains, need, sole_exempt, self.step_of, why)
        judged = _judged_sensors(chosen, tests_ext, gains, n, why, self.step_of)
        kept = [j for j in range(len(chosen)) if judged[j] and (sole_exempt or need[j])]
        kept, rivals = self.not_crosstalk(chosen, kept, why)
        causes = []
        for j in kept:
            label = chosen[j].label
            causes.append(replace(self.described(chosen, f, j, gains),
                                  rivals=tuple(r for r in rivals if r.of == label and not r.better)))
        if random_pose is not None:
            from metrology.diagnosis.posevar import random_pose_cause

            rp = random_pose_cause(random_pose, tests_ext, len(chosen) + 1, self.steps[0].scored, f)
            if rp is None:  # not explained as a pose error: the verdict without it stands
                return None
            why.append(Reason(13, "random_pose_explains", Decision.RANDOM_POSE, (rp[1].label,), "lr_over_one_sensor",
                              random_pose.lr_one_sensor, rules.LR_ONE_SENSOR, step=len(chosen) + 1))
            causes.append(rp[0])  # (its entry, a CandidateResult for it)
            chosen, kept, judged = chosen + [rp[1]], kept + [len(chosen)], judged + [list(range(n))]
        causes.sort(key=lambda c: -c.heldout_gain_chi2)
        best = chosen[kept[0]] if kept else chosen[0]
        tests_ext = replace(tests_ext, p_concerned=battery_on(tests_ext, sorted({i for j in kept for i in judged[j]})))
        if not kept:
            p_all = battery_on(tests_ext, sorted({i for s in chosen for i in _sensors_of(s.component, n)}))
            return Judgement(cause=Outcome.UNEXPLAINED, confidence=Confidence.LOW, best=replace(best, fit=f),
                             tests_extended=replace(tests_ext, p_concerned=p_all), lead=self.lead,
                             rivals=tuple(r for r in rivals if r.better), reasons=tuple(why))
        first = next(s for s in chosen if s.label == causes[0].label)
        confounding = []
        for k, st in enumerate(self.steps):
            if st.chosen is not None:
                confounding += _confounding(st.chosen, [x for x in st.scored if x.significant], why, k + 1)
        for r in rivals:
            if not r.better and any(c.label == r.of for c in causes):
                j = next(k for k in kept if chosen[k].label == r.of)
                confounding.append(Confounding((r.of, r.label),
                                               f"the data cannot tell {r.of} from {r.label} (a shift in proportion "
                                               f"to another sensor's distance, crosstalk, outside the catalogue); "
                                               f"to separate them: {ADVICE[chosen[j].cause]} with more spread of tilt "
                                               f"({r.separate})"))
        weak = weakly_supported([] if sole_exempt else causes)
        for c in causes:
            if c.label in weak:
                why.append(Reason(14, "weak_evidence", Decision.WEAK, (c.label,), "p_heldout_given_others",
                                  c.p_heldout_given_others, rules.ALPHA_HIGH, c.heldout_gain_chi2, c.step))
        confidence = rules.confidence_of(tests_ext.consistent, bool(weak), bool(confounding))
        why.append(Reason(16, "confidence_of", Decision.CONFIDENCE, tuple(c.label for c in causes), "p_battery_extended",
                          tests_ext.p_bonferroni, rules.ALPHA_BATTERY, outcome=confidence))
        return Judgement(cause=first.cause, sensors=first.sensors, confidence=confidence, best=replace(first, fit=f),
                         tests_extended=tests_ext, confounding=confounding, named=causes[0], causes=tuple(causes),
                         lead=self.lead, rivals=tuple(r for r in rivals if any(c.label == r.of for c in causes)),
                         random_pose=random_pose is not None, reasons=tuple(why))

    def step_of(self, label: str) -> int | None:
        """The selection step (from 1) that chose the cause ``label``."""
        return next((k + 1 for k, st in enumerate(self.steps) if st.chosen is not None and st.chosen.label == label),
                    None)

    def not_crosstalk(self, chosen, kept, why: list) -> tuple:
        """``(kept, rivals)``: a cause the registry says crosstalk can mimic is turned down where
        another sensor's distance predicts it significantly better (the rival said), and keeps a
        tie listed as its rival (named, confidence ambiguous, the poses that separate them)."""
        kept, rivals = list(kept), []
        for j in list(kept):
            if "crosstalk" not in chosen[j].component.confused_with:
                continue
            x = self.crosstalk(chosen, j)
            separate = f"metro plan --separate {chosen[j].cause}"
            label, k = chosen[j].label, self.step_of(chosen[j].label)
            if x.better is not None:
                kept.remove(j)
                rivals.append(Rival(x.better, "crosstalk", label, True, x.p, separate))
                # the level split over the other sensors, as crosstalk_check tests it
                why.append(Reason(12, "crosstalk_better", Decision.CROSSTALK_BETTER, (label, x.better), "p_better",
                                  x.p, rules.ALPHA_HELDOUT / (self.n - 1), step=k, outcome=x.better))
            else:
                rivals += [Rival(lab, "crosstalk", label, False, None, separate) for lab in x.indistinguishable]
                if x.indistinguishable:
                    why.append(Reason(12, "crosstalk_as_good", Decision.CROSSTALK_TIE,
                                      (label, *x.indistinguishable), "p_worse", None, rules.ALPHA_CONFOUND, step=k,
                                      outcome=separate))
        return kept, rivals


def _confounding(best: CandidateResult, sig_list, why: list, step: int) -> list[Confounding]:
    """Runner-ups that explain as much (a different cause or sensor), and parameters of the
    named component too correlated with the base geometry (each a Reason appended to ``why``)."""
    out = []
    for other in sig_list:
        if other is best or family_of(other.component) == family_of(best.component):
            continue
        if other.cause == "outliers" and best.cause == "outliers":
            continue  # the step's own gross readings as first flagged, before they were judged given the others
        p_sep = p_better(best, other)
        if rules.indistinguishable(p_sep):
            why.append(Reason(15, "indistinguishable", Decision.CONFOUNDED, (best.label, other.label), "p_separation",
                              p_sep, rules.ALPHA_CONFOUND, step=step))
            out.append(Confounding((best.label, other.label),
                                   f"the data cannot tell {best.label} from {other.label} (held-out gains "
                                   f"indistinguishable, p = {p_sep:.2g}); to separate them: "
                                   f"{ADVICE[best.cause]}; {ADVICE[other.cause]}", p_separation=p_sep))
    f = best.fit
    fc = f.components[-1] if f.components else best.component  # as fitted (outliers re-flagged since)
    if not fc.per_pose:  # its parameters are the last of the fit's (the candidate is fitted last)
        q0 = len(f.corr_base) - fc.n_params
        for q in range(fc.n_params):
            cb_, w = f.corr_base[q0 + q], f.corr_with[q0 + q]
            if rules.poorly_separated(cb_):
                why.append(Reason(15, "poorly_separated", Decision.CONFOUNDED, (best.label, f"{fc.label}.{fc.param_names[q]}", w),
                                  "correlation", float(cb_), rules.CORR_CONFOUND, step=step))
                out.append(Confounding((f"{fc.label}.{fc.param_names[q]}", w),
                                       f"{fc.label}.{fc.param_names[q]} is {cb_:.3f} correlated with the base parameter "
                                       f"{w}: it is poorly separated from the geometry; {ADVICE[fc.name]} would separate "
                                       f"them", correlation=float(cb_)))
    return out


def _sensors_of(comp, n):
    return list(comp.sensors) if comp.sensors else list(range(n))


def _needed_reasons(chosen, gains, need, sole_exempt, step_of, why: list):
    """Rule 10 on each chosen cause: needed given the others (or exempt), or not."""
    for j, s in enumerate(chosen):
        exempt = sole_exempt or s.component.drops_readings
        why.append(Reason(10, "needed_given_others", Decision.NEEDED if need[j] or sole_exempt else Decision.NOT_NEEDED,
                          (s.label,), "p_heldout_given_others", gains[j][1],
                          None if exempt else rules.ALPHA_HELDOUT / max(len(chosen), 1), gains[j][0],
                          step_of(s.label), "exempt" if exempt else None))


def _judged_sensors(chosen, tests_ext, gains, n, why: list, step_of=lambda label: None) -> list:
    """Per chosen cause, the sensors on which it is judged and found consistent with noise
    (empty: not named).

    A cause is named when the joint model leaves its sensors' residuals consistent with the
    noise. A cause that acts on every sensor (``pose_error``, ``plane_form``) is also named
    when it is needed (its held-out gain given the others significant at ``alpha_heldout``)
    and the residuals are consistent on every sensor but those whose remaining structure
    belongs elsewhere: the sensors of another cause chosen (a drift its member follows only in
    part), or, where no other cause is chosen on any failing sensor, one single sensor
    (structure outside the catalogue there). The structure left is said beside the causes.
    Each cause's rule 11 is appended to ``why``.
    """
    fails = {i for i in range(n) if not rules.explains_sensors(battery_on(tests_ext, [i]))}
    out = []
    names = list(tests_ext.sensors)

    def said(s, sensors, p):
        why.append(Reason(11, "explains_sensors", Decision.EXPLAINS if sensors else Decision.NOT_EXPLAINED,
                          (s.label, *(names[i] for i in sensors)), "p_battery_sensors", p, rules.ALPHA_BATTERY,
                          step=step_of(s.label)))
        out.append(sensors)

    for j, s in enumerate(chosen):
        S = _sensors_of(s.component, n)
        p_S = battery_on(tests_ext, S)
        if rules.explains_sensors(p_S):
            said(s, S, p_S)
            continue
        if s.component.sensors or not rules.needed_given_others(gains[j][1], 1):
            said(s, [], p_S)
            continue
        elsewhere = fails & {i for k, o in enumerate(chosen) if k != j for i in o.component.sensors}
        if not elsewhere and len(fails) == 1:
            elsewhere = fails
        rest = [i for i in S if i not in elsewhere]
        p_rest = battery_on(tests_ext, rest) if len(rest) >= 2 else p_S
        ok = len(rest) >= 2 and rules.explains_sensors(p_rest)
        said(s, rest if ok else [], p_rest)
    return out

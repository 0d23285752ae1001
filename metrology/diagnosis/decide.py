"""The diagnosis: the base model's discrepancy, the candidates, the decision, the gain.

:func:`diagnose` is a sequence of named steps (see :mod:`metrology.diagnosis` for the
procedure): :func:`base_analysis`, the forward selection of causes
(:func:`metrology.diagnosis.select.forward_select`, a :class:`~metrology.diagnosis.select.Selection`),
the verdict (:func:`metrology.diagnosis.judge.verdict`, a :class:`~metrology.diagnosis.judge.Judge`),
:func:`side_by_side`, :func:`check_datum`, and the verdict in one paragraph (:func:`verdict_summary`:
part of the result, the ``summary`` of the ``--json`` output, made from the judgement's trail of
reasons, :class:`~metrology.diagnosis.results.Reason`, never re-derived). The decision rules they apply are listed in order in
:mod:`metrology.diagnosis.rules`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from metrology.calibration.dataset import Dataset
from metrology.core.effects import REGISTRY, Covariates, ExtendedModel, PlaneForm
from metrology.core.layout import SensorLayout
from metrology.core.model import readings
from metrology.core.progress import ProgressFn, notify
from metrology.diagnosis import rules
from metrology.diagnosis.candidates import CandidateResult, covariates_for, flag_outliers
from metrology.diagnosis.datum import DatumFormCheck, datum_form, datum_plane, form_agreement, name_datum_plane
from metrology.diagnosis.detectable import detectable_sizes
from metrology.diagnosis.extension import simulated_figures
from metrology.diagnosis.fit import Fit, FitData, clear_all, fit_any, geometry
from metrology.diagnosis.heldout import HeldOut, Problem, kfold
from metrology.diagnosis.judge import Judgement, judge
from metrology.diagnosis.results import (Confidence, Decision, Diagnosis, Discrepancy, HeldOutFigures, Outcome, PlotData,
                                         Reason, Rival, StepFigures)
from metrology.diagnosis.rival import empirical_rivals
from metrology.diagnosis.select import flags_of, forward_select
from metrology.diagnosis.stats import NoiseTests, Trend, battery_on, battery_rng, noise_tests, structure
from metrology.diagnosis.thresholds import THRESHOLDS

__all__ = ["Diagnosis", "PlotData", "BaseAnalysis", "Judgement", "Rival", "diagnose", "base_analysis", "judge",
           "side_by_side", "check_datum", "verdict_summary", "DATUM_DISAGREES"]



@dataclass(frozen=True)
class BaseAnalysis:
    """Step 1: the base calibration and its residuals.

    sigma : (n,) float, mm, the stated noise (or the base fit's own scatter where none);
    cov : Covariates at the calibrated geometry; calibrated : SensorLayout; theta0 : (n, 5)
    float, the start of every later fit; fit : Fit; d0 : (p, n) float, mm; tests : NoiseTests;
    structure : dict, covariate -> sensor name -> Trend (:func:`~metrology.diagnosis.stats.structure`);
    heldout : HeldOut; datum : DatumFormCheck or None
    """

    sigma: np.ndarray
    cov: Covariates
    calibrated: SensorLayout
    theta0: np.ndarray
    fit: Fit
    d0: np.ndarray
    tests: NoiseTests
    structure: dict[str, dict[str, Trend]]
    heldout: HeldOut
    datum: DatumFormCheck | None


def base_analysis(ds: Dataset, folds) -> BaseAnalysis:
    """Calibrate the base model per sensor (covariates at the nominal geometry, then at the
    calibrated one) and test its residuals."""
    nominal, obs = ds.layout, ds.obs
    names = nominal.names
    sigma = nominal.noise_mm.copy()
    cov0 = covariates_for(ds, nominal)
    sig_fit = np.where(np.isfinite(sigma), sigma, 1.0)
    base0 = fit_any(FitData(nominal, obs, cov0, sig_fit), (), None, "lsq")
    if not np.all(np.isfinite(sigma)):  # no stated noise: the base fit's own scatter
        sigma = np.where(np.isfinite(sigma), sigma, np.sqrt(np.nanmean(base0.residual**2, axis=0)))
    zero, u = geometry(nominal, base0.theta)
    calibrated = nominal.with_params(zero, u)
    cov = covariates_for(ds, calibrated)
    theta0 = base0.theta
    data = FitData(nominal, obs, cov, sigma)
    base = fit_any(data, (), theta0, "lsq")
    d0 = readings(zero, u, obs.normal, obs.offset)[0]
    dof_base = np.isfinite(obs.d).sum(axis=0) - 5
    tests = noise_tests(base.residual, sigma, dof_base, names, rng=battery_rng())
    struct = structure(base.residual, d0, cov, names)
    ho_base = kfold(data, (), folds, theta0)
    datum = None if ds.datum_points is None else datum_form(ds, data, zero, u, d0)
    return BaseAnalysis(sigma, cov, calibrated, theta0, base, d0, tests, struct, ho_base, datum)


def side_by_side(problem: Problem, best: CandidateResult | None, flags, sim_reps, rng, empirical=None) -> tuple:
    """The simulation of this data set under the base (and the extended) model beside the
    measurement, and the held-out gains. The extended model is the causes named (``best``) and the
    open search's empirical terms where it took any (``empirical``, a
    :class:`~metrology.diagnosis.search.Empirical`: its fitted terms added to the simulation, its
    held-out residuals on their sensors; the normal deviation stays the causes'). Returns
    (Discrepancy, HeldOutFigures)."""
    ds, b, folds = problem.ds, problem.b, problem.folds
    nominal, sigma, ho_base = ds.layout, b.sigma, b.heldout
    base_model = ExtendedModel(b.calibrated, ())
    sim_rms_b, sim_nd_b, sim_nd_b_sd = simulated_figures(problem, base_model, rng, sim_reps)
    meas_rms = np.sqrt(np.nanmean(b.fit.residual**2, axis=0))
    base_normal = float(np.nanmean(ho_base.normal_dev))
    discrepancy = Discrepancy(list(nominal.names), sigma.tolist(), meas_rms.tolist(), sim_rms_b.tolist(), base_normal,
                              float(sim_nd_b), float(sim_nd_b_sd), sim_reps)
    terms = empirical is not None and empirical.fitted is not None
    if best is None and not terms:
        return discrepancy, HeldOutFigures(folds, ho_base.rms(), base_normal)
    fm = best.fit.model(nominal) if best is not None else base_model
    label = best.label if best is not None else "base"
    ho_e = best.heldout if best is not None else ho_base
    S = list(best.fit.sensors) if best is not None else []
    if terms:
        label += " + empirical(" + ", ".join(dict.fromkeys(f"{t.sensor}: {t.key}" for t in empirical.terms
                                                           if t.key != "tails")) + ")"
        with_terms = np.flatnonzero(np.any(np.isfinite(empirical.heldout[1]), axis=0))
        res = ho_e.residual.copy()
        res[:, with_terms] = empirical.heldout[1][:, with_terms]
        ho_e = HeldOut(res, ho_e.normal_dev)
        S = sorted(set(S) | set(with_terms.tolist()))
    sim_rms_e, sim_nd_e, sim_nd_e_sd = simulated_figures(problem, fm, rng, sim_reps,
                                                         empirical.fitted if terms else None)
    discrepancy = replace(discrepancy, extended_model=label, simulated_extended_residual_rms_mm=sim_rms_e.tolist(),
                          simulated_extended_heldout_normal_rad=float(sim_nd_e),
                          simulated_extended_heldout_normal_sd_rad=float(sim_nd_e_sd))
    excl = flags  # the readings flagged gross by a named outliers cause (None if none is named)
    p_ho = best.p_heldout if best is not None else min(t.p_heldout for t in empirical.terms)
    heldout = HeldOutFigures(
        folds, ho_base.rms(None, excl), base_normal, model=label, extended_rms_mm=ho_e.rms(None, excl),
        rms_ratio=ho_base.rms(None, excl) / ho_e.rms(None, excl),
        base_rms_concerned_mm=ho_base.rms(S, excl), extended_rms_concerned_mm=ho_e.rms(S, excl),
        rms_ratio_concerned=ho_base.rms(S, excl) / ho_e.rms(S, excl),
        extended_normal_rad=float(np.nanmean(ho_e.normal_dev)),
        normal_ratio=float(np.nanmean(ho_base.normal_dev) / np.nanmean(ho_e.normal_dev)), p_heldout=p_ho)
    return discrepancy, heldout


def check_datum(ds, b: BaseAnalysis, v: Judgement, chosen, scored) -> tuple:
    """The readings' own form against the datum cloud's. Returns (datum check with
    ``against_readings``, the judgement ``v`` with its confidence lowered and its trail extended
    where they disagree, rule 17)."""
    # plane_form fitted together with the named causes (a pose error, say, correlates the
    # sensors of a pose; a form fitted without it would carry standard errors too small for
    # the comparison)
    named_forms = [c for c in v.best.fit.components if isinstance(c, PlaneForm)] if v.causes else []
    if named_forms and named_forms[0].order >= 2 and any(c.cause == "plane_form" for c in v.causes):
        pf = v.best.fit
    elif not chosen:  # nothing named: the plane_form candidate's own fit
        pf = next(s.fit for s in scored if s.label == "plane_form")
    else:
        # the quadratic form fitted with the other causes (a form named as scanned has no
        # quadratic coefficients of its own to compare)
        comps = [PlaneForm((), names=ds.layout.names)] + [replace(s.component, values=None, stderr=None)
                                                          for s in chosen if s.cause != "plane_form"]
        pf = fit_any(FitData(ds.layout, ds.obs, b.cov, b.sigma), comps, b.theta0)
    ag = replace(form_agreement(b.datum, pf), fitted_with=tuple(c.label for c in pf.components))
    if named_forms and named_forms[0].order == 0 and any(c.cause == "plane_form" for c in v.causes):
        # the form named is the scan itself: the readings agree with the cloud when they see it
        # at gain 1 (a two-sided z-test of the gain's standard error)
        from scipy import stats

        g, se = float(named_forms[0].values[2]), float(named_forms[0].stderr[2])
        p_g = float(2 * stats.norm.sf(abs(g - 1.0) / max(se, 1e-300)))
        ag = replace(ag, scan_gain=g, scan_gain_stderr=se, p=p_g, agree=rules.datum_agrees(p_g),
                     fitted_with=tuple(c.label for c in v.best.fit.components))
    if not ag.agree:
        confidence = rules.confidence_given_datum(v.confidence, v.cause, ag.agree)
        v = replace(v, confidence=confidence, reasons=v.reasons + (
            Reason(17, "datum_agrees", Decision.DATUM_DISAGREES, ag.fitted_with, "p_form", ag.p,
                   rules.ALPHA_FORM, outcome=confidence),))
    return replace(b.datum, against_readings=ag), v


def _steps_table(b: BaseAnalysis, steps, v: Judgement) -> list[StepFigures]:
    """The residuals after each step: per sensor in-sample RMS and held-out RMS (mm), and
    whether the cause it added is named in the verdict ``v`` (a step's cause can be turned down
    after the selection: not needed given the others, crosstalk, its sensors not explained)."""
    out = [StepFigures(None, "base", np.sqrt(np.nanmean(b.fit.residual**2, axis=0)).tolist(), b.heldout.rms())]
    labels, named = [], {c.label for c in v.causes}
    for st in steps:
        if st.chosen is None:
            break
        labels.append(st.chosen.label)
        out.append(StepFigures(st.chosen.label, "base + " + " + ".join(labels),
                               np.sqrt(np.nanmean(st.chosen.fit.residual**2, axis=0)).tolist(), st.chosen.heldout.rms(),
                               st.chosen.p_heldout, st.chosen.heldout_chi2_reduction, st.chosen.label in named))
    return out


def diagnose(ds: Dataset, folds: int = 5, sim_reps: int = 2, seed: int = 0, progress: ProgressFn | None = None) -> Diagnosis:
    """Run the full diagnosis on a :class:`~metrology.calibration.dataset.Dataset` (see
    :mod:`metrology.diagnosis`).

    ``folds``: k of the k-fold by pose; ``sim_reps``: simulated copies of the data set per
    side-by-side figure; ``seed``: of the simulation's noise (the diagnosis itself is
    deterministic); ``progress(done, total, what)``: called at each of the 5 stages and
    before each candidate is scored.
    """
    p = ds.obs.d.shape[0]
    if p < 2 * folds:
        raise ValueError(f"{p} poses: need at least {2 * folds} for {folds}-fold held-out figures")
    clear_all()  # the fits kept are this data set's: none of an earlier one can be asked for again
    # the null includes the datum's uncertainty: the data set on the plane the readings place
    # under the scan's covariance (issue 40; metrology.diagnosis.datum.datum_plane)
    scan = ds
    ds, plane_check = datum_plane(scan)
    diag = _diagnose_on(ds, folds, sim_reps, seed, progress)
    if plane_check.off:  # the first test is a screen: off only given the causes named (rule 18)
        given = plane_given(scan, ds, plane_check, diag)
        plane_check = replace(plane_check, given_causes=given, screen_p=plane_check.p,
                              off=rules.datum_plane_off(given.p))
        if not plane_check.off:  # the plane under the scan's covariance, as for a plane not off
            ds, first = datum_plane(scan, widen=False)
            plane_check = replace(first, off=False, given_causes=given, screen_p=first.p)
            diag = _diagnose_on(ds, folds, sim_reps, seed, progress)
    return name_datum_plane(diag, plane_check)


def plane_given(scan, ds, check, diag: Diagnosis):
    """Rule 18's test of the plane the diagnosis ``diag`` ran on (``ds``, moved from the scan's
    plane of ``scan`` by ``check.phi``) given the causes it named
    (:func:`~metrology.diagnosis.planegiven.plane_given_causes`)."""
    from metrology.diagnosis.planegiven import plane_given_causes

    pd = diag.plot_data
    named = diag.outcome == Outcome.NAMED and pd.best is not None
    fit = pd.best.fit if named else pd.base
    rand = next((c for c in diag.causes if c.label.endswith("@random")), None)
    rp = None if rand is None else (rand.params["sigma_position_mm"].value ** 2, rand.params["sigma_tilt_rad"].value ** 2)
    labels = tuple(c.label for c in diag.causes) if named else ()
    return plane_given_causes(ds, scan.plane, scan.plane_cov, check.phi, fit, pd.cov, pd.sigma, labels, rp)


def _diagnose_on(ds: Dataset, folds, sim_reps, seed, progress) -> Diagnosis:
    """The diagnosis of ``ds`` on its plane (:func:`diagnose` without the datum plane's test)."""
    rng = np.random.default_rng(seed)
    notify(progress, 0, 5, "base model and its held-out figures")
    b = base_analysis(ds, folds)
    flags, p_out = flag_outliers(ds.layout, ds.obs, b.cov, b.sigma, b.theta0)
    steps = forward_select(ds, b, flags, p_out, folds, on_candidate=lambda k, i, n, label: notify(
        progress, 1, 5, f"selection step {k}: candidate {i + 1}/{n} ({label})"))
    chosen = [st.chosen for st in steps if st.chosen is not None]
    notify(progress, 2, 5, "verdict and the causes' gains")
    problem = Problem(ds, b, folds)
    v = judge(problem, steps, rng)
    if v.dropped is not None:  # nothing named: the sole cause chosen is not in the model
        chosen = []
    rand = v.random_pose  # a random pose error predicts no reading: not in the model
    fitted = [s for s in chosen if not (rand and s.component.per_pose)]  # joint model, last step's held-out
    joint = replace(fitted[-1], fit=v.best.fit, label="+".join(s.label for s in fitted)) if fitted else (
        replace(v.best, heldout=b.heldout) if rand else None)
    gross = np.zeros(ds.obs.d.shape, bool) if (named_flags := flags_of(chosen)) is None else named_flags
    v, beaten = empirical_rivals(ds, b, v, chosen, gross, folds)  # rule 22: the catalogue against the search
    if beaten and v.outcome != Outcome.NAMED:  # the sole cause is not named: the base model is judged
        chosen, joint, named_flags = [], None, None
        gross = np.zeros(ds.obs.d.shape, bool)
    scored = steps[0].scored
    datum = b.datum
    if datum is not None:
        notify(progress, 3, 5, "datum check")
        datum, v = check_datum(ds, b, v, chosen, scored)
    empirical = None
    named = {c.label for c in v.causes}
    tied = v.outcome == Outcome.NAMED and rules.search_beside(v.confidence, any(  # a rival: the search beside the cause
        r.decided in (Decision.EMPIRICAL_TIE, Decision.CROSSTALK_TIE) and r.concerns[0] in named for r in v.reasons))
    if rules.search_tried(v.cause, v.confidence) or tied:  # the catalogue does not explain: the open search
        empirical = open_search(ds, b, v, gross, folds, base=tied)  # a tie: the rival beside the cause
    notify(progress, 4, 5, "side-by-side simulation")
    discrepancy, heldout = side_by_side(problem, joint, named_flags, sim_reps, rng, None if tied else empirical)
    summary = verdict_summary(v, b.tests) + ("" if empirical is None else empirical_text(empirical, tied))
    notify(progress, 5, 5, "done")

    def held(ho):
        return None if ho is None else np.where(gross, np.nan, ho.residual)

    plot = PlotData(b.fit, b.cov, b.d0, v.best, ds.layout.names, b.sigma, flags if named_flags is None else named_flags,
                    b.structure, held(b.heldout), held(None if joint is None else joint.heldout))
    return Diagnosis(empirical=empirical, reasons=v.reasons + (() if empirical is None else empirical.reasons),
                     cause=v.cause, sensors=v.sensors, confidence=v.confidence, summary=summary, named=v.named,
                     candidates=tuple(scored), tests_base=b.tests, tests_extended=v.tests_extended,
                     structure_base=b.structure, discrepancy=discrepancy, heldout=heldout, confounding=v.confounding,
                     base_theta=b.fit.theta, base_stderr=b.fit.theta_stderr, thresholds=dict(THRESHOLDS),
                     datum_form=datum, plot_data=plot, causes=v.causes, steps=tuple(_steps_table(b, steps, v)),
                     detectable=detectable_sizes(steps[0].scored, b, np.isfinite(ds.obs.d).sum(axis=0), ds))


def open_search(ds, b: BaseAnalysis, v: Judgement, gross, folds, base=False):
    """The open search (:func:`metrology.diagnosis.search.search`) on the residuals of the model the
    verdict judged (the causes named; the base model where none is, or where ``base``: a cause tied
    with a term by rule 22, the search then says what predicts as well as the cause), the readings
    named gross left out."""
    from metrology.core.model import jacobian_raw
    from metrology.diagnosis.search import search

    fit = v.best.fit if v.outcome == Outcome.NAMED and v.best is not None and not base else b.fit
    zero, u = geometry(ds.layout, fit.theta)
    J = jacobian_raw(zero, u, ds.obs.normal, ds.obs.offset)
    return search(ds, b.cov, b.d0, np.where(gross, np.nan, fit.residual), b.sigma, J, folds)


def empirical_text(e, beside: bool = False) -> str:
    """The summary's sentence on the open search's terms (none: what was tried); ``beside``: run on the
    base residuals beside an ambiguous cause (rule 19), its terms what the cause's fit took."""
    if not e.terms:
        return (f"; the open search found no term of the run's variables that predicts held-out poses better "
                f"({e.n_tried} terms tried)")
    lead = ("; beside the cause, the open search on the base residuals: " if beside else
            "; outside the catalogue, an empirical model: ")
    return (lead + "; ".join(
        f"{t.equation} (held-out chi-square gain {t.gain_chi2:.3g}, p = {t.p_heldout:.2g})" for t in e.terms)
        + f" ({e.n_tried} terms tried, in-sample level {e.level:.2g} for a variable's one term)" + (
            "" if e.heldout_rms_mm is None else
            f"; held-out RMS on its sensors {1e3 * e.heldout_rms_mm[0]:.3g} um without the terms, "
            f"{1e3 * e.heldout_rms_mm[1]:.3g} um with them"))


# -- the verdict in one paragraph, made from the trail of reasons -----------------------------------

#: appended to the summary when the datum cloud's form disagrees with the readings'
DATUM_DISAGREES = ("; the datum cloud's form disagrees with the readings' (p = {p:.2g}): "
                   "the datum changed between scan and run, or the cloud is not of the surface the beams saw")


def _lead_text(in_only) -> str:
    if in_only is None:
        return ""
    return (f"; {in_only.label} fits in sample (p = {in_only.p_insample:.2g}) but does not predict held-out "
            f"poses significantly better (p = {in_only.p_heldout:.2g}, RMS ratio "
            f"{in_only.heldout_rms_ratio:.3g}): too small, or too confounded, to name")


def _last(reasons, decided: Decision) -> Reason | None:
    return next((r for r in reversed(reasons) if r.decided == decided), None)


def verdict_summary(v, tb) -> str:
    """One paragraph of the judgement ``v`` (:class:`~metrology.diagnosis.judge.Judgement`), made
    from its trail ``v.reasons`` (which rule decided, on what, with which figures) and the causes
    it named; ``tb`` the noise tests on the base residuals. Several causes are named together,
    and structure that remains beside them is said."""
    why = v.reasons
    worst = max(tb.sensors.items(), key=lambda kv: kv[1].chi2 / kv[1].dof)
    lead = _lead_text(v.lead) if _last(why, Decision.LEAD) is not None else ""
    te = v.tests_extended
    consistent = f"residuals consistent with the stated noise (battery p = {tb.p_bonferroni:.2g})"
    inconsistent = (f"residuals inconsistent with the noise model (battery p = {tb.p_bonferroni:.2g}, worst "
                    f"{worst[0]}: sigma {worst[1].sigma_est_mm:.4g} mm)")
    nothing_above = "no effect above the detectable sizes (smaller ones are not ruled out)"
    datum = _last(why, Decision.DATUM_DISAGREES)
    tail = "" if datum is None else DATUM_DISAGREES.format(p=datum.value)
    dropped = _last(why, Decision.DROPPED)  # rule 10 on a sole cause
    if dropped is not None:
        chose = next(r for r in why if r.decided == Decision.CHOSEN and r.step == dropped.step)
        turned = (f"{dropped.concerns[0]} was selected (held-out p = {chose.value:.2g} at its step) but is not needed "
                  f"against the base model (held-out chi-square gain {dropped.gain:.3g}, p = {dropped.value:.2g}), so "
                  "it is not named")
        if v.cause == Outcome.NONE:
            return f"{consistent}; {turned}: {nothing_above}" + lead + tail
        return f"{inconsistent}; {turned}: no catalogued cause explains the structure" + lead + tail
    if v.cause == Outcome.NONE:
        return f"{consistent}; no candidate gives a significant held-out gain: {nothing_above}" + lead + tail
    if v.best is None:
        return (f"{inconsistent} and no catalogued effect gives a significant held-out gain: structure outside the "
                "catalogue" + lead + tail)
    rival = [r for r in why if r.decided == Decision.EMPIRICAL_BETTER]
    rival_text = "; ".join(f"{r.concerns[1]} (a term of the run's variables, outside the catalogue) predicts held-out "
                           f"poses better than {r.concerns[0]} (p = {r.value:.2g})" for r in rival)
    if v.cause == Outcome.UNEXPLAINED and rival:
        return f"{inconsistent}; {rival_text}: not named" + tail
    better = next((r for r in why if r.decided == Decision.CROSSTALK_BETTER), None)
    if v.cause == Outcome.UNEXPLAINED and better is not None:
        return (f"{v.best.label} gives a significant held-out gain, but {better.outcome} (crosstalk: predicts held-out "
                f"poses better than {better.concerns[0]}, p = {better.value:.2g}): the effect follows another "
                "sensor's distance, which is outside the catalogue (crosstalk between sensors, a shared supply)" + tail)
    if v.cause == Outcome.UNEXPLAINED:
        return (f"{v.best.label} gives a significant held-out gain (RMS ratio {v.best.heldout_rms_ratio:.3g}) but "
                f"leaves the residuals of its sensors inconsistent with the noise model (battery p = "
                f"{te.p_concerned:.2g}): a partial explanation at best; structure outside the catalogue remains" + tail)
    parts = []
    for c in v.causes:
        where = f" on {', '.join(c.sensors)}" if c.sensors and not REGISTRY[c.cause].setup else ""
        test = (f"{c.test}, p = {c.p_insample:.2g}" if c.test else
                f"held-out chi-square gain {c.heldout_gain_chi2:.3g} given the others, p = {c.p_heldout_given_others:.2g}")
        parts.append(f"{c.cause}{where} ({c.label}: {test})")
    text = " and ".join(parts) + f" named; their sensors' residuals then consistent with noise (p = {te.p_concerned:.2g})"
    if not te.consistent:
        names = list(te.sensors)
        where = [k for i, k in enumerate(names) if not rules.explains_sensors(battery_on(te, [i]))]
        where = where or [max(te.sensors.items(), key=lambda kv: kv[1].chi2 / kv[1].dof)[0]]
        text += (f"; structure remains on {', '.join(where)} (battery p = {te.p_bonferroni:.2g}): another effect, "
                 "or a false alarm of the tests")
    if rival:  # rule 22 on one of several causes
        return text + f"; confidence ambiguous: {rival_text}" + tail
    tied = [r for r in why if r.decided == Decision.EMPIRICAL_TIE]
    confidence = _last(why, Decision.CONFIDENCE).outcome  # rule 16's (before the datum's, rule 17)
    named = {c.label for c in v.causes}
    ties = [r for r in why if r.decided == Decision.CROSSTALK_TIE and r.concerns[0] in named]
    ties = ties if ties and (tied or confidence == Confidence.AMBIGUOUS) else []
    if tied or ties:  # rule 22's search terms and rule 12's crosstalk, each rival named, and the poses that separate
        return text + "; confidence ambiguous: " + "; ".join([
            *(f"{r.concerns[1]} (a term of the run's variables, outside the catalogue) predicts held-out poses as "
              f"well as {r.concerns[0]} (p = {r.value:.2g} that it predicts better)" for r in tied
              if r.statistic != "correlation"),
            *(f"{r.concerns[1]} (a term of the run's variables, outside the catalogue) is the same curve as "
              f"{r.concerns[0]} on this run (correlation {r.value:.3f}, at least {r.threshold:g})" for r in tied
              if r.statistic == "correlation"),
            *(f"{', '.join(r.concerns[1:])} (a shift in proportion to another sensor's distance, crosstalk, outside "
              f"the catalogue) predicts held-out poses as well as {r.concerns[0]}" for r in ties)]) + (
            f"; poses that separate them: {', '.join(dict.fromkeys(r.outcome for r in ties))}" if ties else "") + tail
    weak = [r for r in why if r.decided == Decision.WEAK] if confidence == Confidence.MODERATE else []
    if weak:
        return text + (f"; confidence moderate: weak held-out evidence for "
                       f"{' and '.join(f'{r.concerns[0]} (p = {r.value:.2g})' for r in weak)}, not below "
                       f"{weak[0].threshold:g}") + tail
    return text + f"; confidence {confidence}" + tail

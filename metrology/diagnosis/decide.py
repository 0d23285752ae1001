"""The diagnosis: the base model's discrepancy, the candidates, the decision, the gain.

:func:`diagnose` is a sequence of named steps (see :mod:`metrology.diagnosis` for the
procedure): :func:`base_analysis`, the forward selection of causes
(:func:`metrology.diagnosis.select.forward_select`), :func:`verdict`, :func:`side_by_side`,
:func:`check_datum`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from metrology.calibration.dataset import Dataset
from metrology.core.effects import ExtendedModel, PlaneForm
from metrology.core.layout import SensorLayout
from metrology.core.progress import ProgressFn, notify
from metrology.core.model import readings
from metrology.diagnosis.candidates import CandidateResult, covariates_for, flag_outliers
from metrology.diagnosis.crosstalk import crosstalk_check
from metrology.diagnosis.datum import DatumFormCheck, datum_form, form_agreement
from metrology.diagnosis.detectable import detectable_sizes
from metrology.diagnosis.extension import describe_named, simulated_figures, size_of, with_model_spread
from metrology.diagnosis.fit import Fit, fit_any, geometry, residual_battery
from metrology.diagnosis.heldout import HeldOut, kfold
from metrology.diagnosis.results import Cause, Diagnosis, PlotData, Rival
from metrology.diagnosis.select import drop_one_gains, family_of, flags_of, forward_select, joint_fit, needed, p_better, weakly_supported
from metrology.diagnosis.stats import NoiseTests, battery_on, battery_rng, noise_tests, structure
from metrology.diagnosis.summary import DATUM_DISAGREES, verdict_summary
from metrology.diagnosis import rules
from metrology.diagnosis.thresholds import ADVICE, THRESHOLDS

__all__ = ["Diagnosis", "PlotData", "BaseAnalysis", "Verdict", "Rival", "diagnose", "base_analysis", "verdict",
           "side_by_side", "check_datum"]



@dataclass(frozen=True)
class BaseAnalysis:
    """Step 1: the base calibration and its residuals.

    sigma : (n,) float, mm, the stated noise (or the base fit's own scatter where none);
    cov : Covariates at the calibrated geometry; calibrated : SensorLayout; theta0 : (n, 5)
    float, the start of every later fit; fit : Fit; d0 : (p, n) float, mm; tests : NoiseTests;
    structure : dict; heldout : HeldOut; datum : DatumFormCheck or None
    """

    sigma: np.ndarray
    cov: object
    calibrated: SensorLayout
    theta0: np.ndarray
    fit: Fit
    d0: np.ndarray
    tests: NoiseTests
    structure: dict
    heldout: HeldOut
    datum: DatumFormCheck | None


@dataclass(frozen=True)
class Verdict:
    """Steps 3-4: the first cause, its sensors and confidence, the first named candidate (its
    ``fit`` the joint model of every cause, refitted by ``lsq``; or None), the noise tests after
    the extension, the confounding notes, the first cause's description, every named cause's
    description (largest held-out gain given the others first), the lead (a candidate
    significant in sample only, when the selection stopped) and ``dropped``: a sole cause the
    selection chose that is not needed against the base model (its label, its step's held-out
    p, and its held-out chi-square gain and p against the base model), so not named."""

    cause: str
    sensors: list
    confidence: str
    best: CandidateResult | None
    tests_extended: NoiseTests | None
    confounding: list
    named: dict | None
    causes: tuple = ()
    lead: CandidateResult | None = None
    dropped: dict | None = None
    rivals: tuple = ()
    random_pose: bool = False


def base_analysis(ds: Dataset, folds) -> BaseAnalysis:
    """Calibrate the base model per sensor (covariates at the nominal geometry, then at the
    calibrated one) and test its residuals."""
    nominal, obs = ds.layout, ds.obs
    names = nominal.names
    sigma = nominal.noise_mm.copy()
    cov0 = covariates_for(ds, nominal)
    sig_fit = np.where(np.isfinite(sigma), sigma, 1.0)
    base0 = fit_any(nominal, obs, cov0, sig_fit, (), None, "lsq")
    if not np.all(np.isfinite(sigma)):  # no stated noise: the base fit's own scatter
        sigma = np.where(np.isfinite(sigma), sigma, np.sqrt(np.nanmean(base0.residual**2, axis=0)))
    zero, u = geometry(nominal, base0.theta)
    calibrated = nominal.with_params(zero, u)
    cov = covariates_for(ds, calibrated)
    theta0 = base0.theta
    base = fit_any(nominal, obs, cov, sigma, (), theta0, "lsq")
    d0 = readings(zero, u, obs.normal, obs.offset)[0]
    dof_base = np.isfinite(obs.d).sum(axis=0) - 5
    tests = noise_tests(base.residual, sigma, dof_base, names, rng=battery_rng())
    struct = structure(base.residual, d0, cov, names)
    ho_base = kfold(nominal, obs, cov, sigma, (), folds, theta0)
    datum = None if ds.datum_points is None else datum_form(ds, zero, u, obs, cov, d0, sigma)
    return BaseAnalysis(sigma, cov, calibrated, theta0, base, d0, tests, struct, ho_base, datum)


def _confounding(best: CandidateResult, sig_list) -> list:
    """Runner-ups that explain as much (a different cause or sensor), and parameters of the
    named component too correlated with the base geometry."""
    out = []
    for other in sig_list:
        if other is best or family_of(other.component) == family_of(best.component):
            continue
        p_sep = p_better(best, other)
        if rules.indistinguishable(p_sep):
            out.append({
                "between": [best.label, other.label], "p_separation": p_sep,
                "message": f"the data cannot tell {best.label} from {other.label} (held-out gains "
                           f"indistinguishable, p = {p_sep:.2g}); to separate them: "
                           f"{ADVICE[best.cause]}; {ADVICE[other.cause]}",
            })
    f = best.fit
    fc = f.components[-1] if f.components else best.component  # as fitted (outliers re-flagged since)
    if not fc.per_pose:  # its parameters are the last of the fit's (the candidate is fitted last)
        q0 = len(f.corr_base) - fc.n_params
        for q in range(fc.n_params):
            cb_, w = f.corr_base[q0 + q], f.corr_with[q0 + q]
            if rules.poorly_separated(cb_):
                out.append({
                    "between": [f"{fc.label}.{fc.param_names[q]}", w], "correlation": float(cb_),
                    "message": f"{fc.label}.{fc.param_names[q]} is {cb_:.3f} correlated with the base parameter "
                               f"{w}: it is poorly separated from the geometry; {ADVICE[fc.name]} would separate them",
                })
    return out


def _sensors_of(comp, n):
    return list(comp.sensors) if comp.sensors else list(range(n))


def _judged_sensors(chosen, tests_ext, gains, n) -> list:
    """Per chosen cause, the sensors on which it is judged and found consistent with noise
    (empty: not named).

    A cause is named when the joint model leaves its sensors' residuals consistent with the
    noise. A cause that acts on every sensor (``pose_error``, ``plane_form``) is also named
    when it is needed (its held-out gain given the others significant at ``alpha_heldout``)
    and the residuals are consistent on every sensor but those whose remaining structure
    belongs elsewhere: the sensors of another cause chosen (a drift its member follows only in
    part), or, where no other cause is chosen on any failing sensor, one single sensor
    (structure outside the catalogue there). The structure left is said beside the causes.
    """
    fails = {i for i in range(n) if not rules.explains_sensors(battery_on(tests_ext, [i]))}
    out = []
    for j, s in enumerate(chosen):
        S = _sensors_of(s.component, n)
        if rules.explains_sensors(battery_on(tests_ext, S)):
            out.append(S)
            continue
        if s.component.sensors or not rules.needed_given_others(gains[j][1], 1):
            out.append([])
            continue
        elsewhere = fails & {i for k, o in enumerate(chosen) if k != j for i in o.component.sensors}
        if not elsewhere and len(fails) == 1:
            elsewhere = fails
        rest = [i for i in S if i not in elsewhere]
        ok = len(rest) >= 2 and rules.explains_sensors(battery_on(tests_ext, rest))
        out.append(rest if ok else [])
    return out


def verdict(ds, b: BaseAnalysis, steps, folds, rng) -> Verdict:
    """Steps 3-4: refit the selected causes jointly, keep those whose sensors' residuals are then
    consistent with noise, and describe each with its size, its held-out gain given the others and
    what the data cannot separate. Where structure remains and no rigid pose error could be fitted
    (3 sensors), the pose error as a random effect (:mod:`metrology.diagnosis.posevar`)."""
    from metrology.diagnosis.posevar import random_pose_stage

    v = _verdict(ds, b, steps, folds, rng)
    rpe = random_pose_stage(ds, b, steps, battery_rng()) if rules.random_pose_tried(v.cause, v.confidence) else None
    # a sole cause turned down as not needed stays turned down beside the random pose error
    v2 = None if rpe is None else _verdict(ds, b, steps, folds, rng, random_pose=rpe, exempt_sole=v.dropped is None)
    return v2 if v2 is not None and v2.random_pose else v


def _verdict(ds, b: BaseAnalysis, steps, folds, rng, random_pose=None, exempt_sole=True) -> Verdict:
    """:func:`verdict`; with ``random_pose`` (of :func:`~metrology.diagnosis.posevar.random_pose_stage`)
    the pose error is a random effect, and the residuals are judged whitened by it; a sole fixed
    cause beside it is then exempt from the drop-one test (``exempt_sole``) unless the verdict
    without it turned that cause down."""
    nominal, obs = ds.layout, ds.obs
    n = obs.d.shape[1]
    chosen = [s.chosen for s in steps if s.chosen is not None and (random_pose is None or not s.chosen.component.per_pose)]
    lead = steps[-1].lead
    if not chosen and random_pose is None:
        cause = "none" if b.tests.consistent else "unexplained"
        return Verdict(cause, [], rules.confidence_of_nothing(b.tests.consistent, lead is not None), None, None, [],
                       None, (), lead)
    f = joint_fit(ds, b, chosen) if random_pose is None else random_pose[1]
    if random_pose is None:
        tests_ext = residual_battery(f, obs, b.cov, b.sigma, nominal.names)
    else:  # the residuals whitened by the fitted pose error's covariance (the fit has no rigid one);
        # a pose error need not be Gaussian: no normality test
        r_test = random_pose[0].whitened
        tests_ext = noise_tests(r_test, b.sigma, np.isfinite(r_test).sum(axis=0) - 5.0, nominal.names,
                                pairs=not any(c.per_pose for c in f.components), rng=battery_rng(),
                                normality=False)
    gains = drop_one_gains(ds, b, chosen, folds) if chosen else []
    need = needed(chosen, gains)
    if random_pose is None and len(chosen) == 1 and not need[0]:
        # a sole cause whose held-out gain against the base model is not significant (a null's
        # datum "form", selected at p = 0.032 beyond the plane's tilt, gave 0.056): not named
        cause = "none" if b.tests.consistent else "unexplained"
        dropped = {"label": chosen[0].label, "p_step": chosen[0].p_heldout, "gain_chi2": gains[0][0],
                   "p_base": gains[0][1]}
        return Verdict(cause, [], "low", None, None, [], None, (), lead, dropped)
    judged = _judged_sensors(chosen, tests_ext, gains, n)
    # beside the random pose error a sole fixed cause keeps its step's test (its drop-one gain
    # is taken without the random effect), unless the verdict without it turned it down
    sole_exempt = random_pose is not None and len(chosen) == 1 and exempt_sole
    kept = [j for j in range(len(chosen)) if judged[j] and (sole_exempt or need[j])]
    # crosstalk rules (the check is in metrology.diagnosis.crosstalk), at alpha_heldout and alpha_confound:
    # - crosstalk_better: a characteristic that another sensor's distance predicts significantly
    #   better is crosstalk, not the sensor's own: not named, the rival said;
    # - crosstalk_tie: one that crosstalk predicts only as well is named, confidence ambiguous,
    #   the rival listed (gain errors are common, crosstalk rare; a user with no cause at all
    #   gets nothing to act on), with the poses that would separate them
    xtalk, rivals = {}, []
    for j in list(kept):
        if "crosstalk" in chosen[j].component.confused_with:
            xtalk[j] = x = crosstalk_check(ds, b, tuple(s.component for s in chosen[:j]), chosen[j], folds)
            separate = f"metro plan --separate {chosen[j].cause}"
            if x["better"] is not None:
                kept.remove(j)
                rivals.append(Rival(x["better"], "crosstalk", chosen[j].label, True, x["p"], separate))
            else:
                rivals += [Rival(lab, "crosstalk", chosen[j].label, False, None, separate)
                           for lab in x["indistinguishable"]]
    causes = []
    for j in kept:
        s = chosen[j]
        d = describe_named(f, nominal, obs, b.cov, b.sigma, rng, which=j, theta_ref=b.theta0)
        size = with_model_spread(size_of(f, j, b.cov, b.d0), s, steps[j].scored, b.cov, b.d0)
        d.update({"cause": s.cause, "sensors": s.sensors, "size": size,
                  "heldout_gain_chi2": gains[j][0], "p_heldout_given_others": gains[j][1],
                  "p_insample": s.p_insample, "step": j + 1})
        causes.append(Cause.from_description(d, [r for r in rivals if r.of == s.label and not r.better]))
    if random_pose is not None:
        from metrology.diagnosis.posevar import random_pose_cause

        rp = random_pose_cause(random_pose[0], tests_ext, len(chosen) + 1, steps[0].scored, f)
        if rp is None:  # not explained as a pose error: the verdict without it stands
            return None
        causes.append(rp[0])  # (its entry, a CandidateResult for it)
        chosen, kept, judged = chosen + [rp[1]], kept + [len(chosen)], judged + [list(range(n))]
    causes.sort(key=lambda c: -c.heldout_gain_chi2)
    best = chosen[kept[0]] if kept else chosen[0]
    p_concerned = battery_on(tests_ext, sorted({i for j in kept for i in judged[j]}))
    tests_ext = replace(tests_ext, p_concerned=p_concerned)
    if not kept:
        p_all = battery_on(tests_ext, sorted({i for s in chosen for i in _sensors_of(s.component, n)}))
        return Verdict("unexplained", [], "low", replace(best, fit=f), replace(tests_ext, p_concerned=p_all), [],
                       None, (), lead, rivals=tuple(r for r in rivals if r.better))
    first = next(s for s in chosen if s.label == causes[0].label)
    confounding = []
    for st in steps:
        if st.chosen is not None:
            confounding += _confounding(st.chosen, [x for x in st.scored if x.significant])
    for r in rivals:
        if not r.better and any(c.label == r.of for c in causes):
            j = next(k for k in kept if chosen[k].label == r.of)
            confounding.append({"between": [r.of, r.label], "p_separation": None,
                                "message": f"the data cannot tell {r.of} from {r.label} (a shift in proportion "
                                           f"to another sensor's distance, crosstalk, outside the catalogue); "
                                           f"to separate them: {ADVICE[chosen[j].cause]} with more spread of tilt "
                                           f"({r.separate})"})
    confidence = rules.confidence_of(tests_ext.consistent, bool(weakly_supported([] if sole_exempt else causes)),
                                     bool(confounding))
    return Verdict(first.cause, first.sensors, confidence, replace(first, fit=f), tests_ext, confounding,
                   causes[0], tuple(causes), lead, rivals=tuple(r for r in rivals if any(c.label == r.of for c in causes)),
                   random_pose=random_pose is not None)


def side_by_side(ds, b: BaseAnalysis, best: CandidateResult | None, flags, folds, sim_reps, rng):
    """The simulation of this data set under the base (and the extended) model beside the
    measurement, and the held-out gains. Returns (discrepancy dict, heldout dict)."""
    nominal, obs, sigma, cov, theta0, ho_base = ds.layout, ds.obs, b.sigma, b.cov, b.theta0, b.heldout
    base_model = ExtendedModel(b.calibrated, ())
    sim_rms_b, sim_nd_b, sim_nd_b_sd = simulated_figures(nominal, obs, cov, sigma, base_model, folds, theta0, rng,
                                                         sim_reps)
    meas_rms = np.sqrt(np.nanmean(b.fit.residual**2, axis=0))
    discrepancy = {
        "sensors": list(nominal.names),
        "stated_noise_mm": sigma.tolist(),
        "measured_residual_rms_mm": meas_rms.tolist(),
        "simulated_base_residual_rms_mm": sim_rms_b.tolist(),
        "measured_heldout_normal_deg": float(np.rad2deg(np.nanmean(ho_base.normal_dev))),
        "simulated_base_heldout_normal_deg": float(np.rad2deg(sim_nd_b)),
        "simulated_base_heldout_normal_sd_deg": float(np.rad2deg(sim_nd_b_sd)),
        "sim_reps": sim_reps,
    }
    heldout = {"folds": folds, "base_rms_mm": ho_base.rms(),
               "base_normal_deg": float(np.rad2deg(np.nanmean(ho_base.normal_dev)))}
    if best is None:
        return discrepancy, heldout
    fm = best.fit.model(nominal)
    sim_rms_e, sim_nd_e, sim_nd_e_sd = simulated_figures(nominal, obs, cov, sigma, fm, folds, theta0, rng, sim_reps)
    discrepancy["simulated_extended_residual_rms_mm"] = sim_rms_e.tolist()
    discrepancy["simulated_extended_heldout_normal_deg"] = float(np.rad2deg(sim_nd_e))
    discrepancy["simulated_extended_heldout_normal_sd_deg"] = float(np.rad2deg(sim_nd_e_sd))
    discrepancy["extended_model"] = best.label
    ho_e = best.heldout
    excl = flags  # the readings flagged gross by a named outliers cause (None if none is named)
    S = list(best.fit.sensors)
    heldout.update({
        "model": best.label,
        "base_rms_mm": ho_base.rms(None, excl), "extended_rms_mm": ho_e.rms(None, excl),
        "rms_ratio": ho_base.rms(None, excl) / ho_e.rms(None, excl),
        "base_rms_concerned_mm": ho_base.rms(S, excl), "extended_rms_concerned_mm": ho_e.rms(S, excl),
        "rms_ratio_concerned": ho_base.rms(S, excl) / ho_e.rms(S, excl),
        "extended_normal_deg": float(np.rad2deg(np.nanmean(ho_e.normal_dev))),
        "normal_ratio": float(np.nanmean(ho_base.normal_dev) / np.nanmean(ho_e.normal_dev)),
        "p_heldout": best.p_heldout,
    })
    return discrepancy, heldout


def check_datum(ds, b: BaseAnalysis, v: Verdict, chosen, scored, confidence, summary):
    """The readings' own form against the datum cloud's. Returns (datum check with
    ``against_readings``, confidence, summary), lowered and extended when they disagree."""
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
        pf = fit_any(ds.layout, ds.obs, b.cov, b.sigma, comps, b.theta0)
    ag = form_agreement(b.datum, pf)
    ag["fitted_with"] = [c.label for c in pf.components]
    if named_forms and named_forms[0].order == 0 and any(c.cause == "plane_form" for c in v.causes):
        # the form named is the scan itself: the readings agree with the cloud when they see it
        # at gain 1 (a two-sided z-test of the gain's standard error)
        from scipy import stats

        g, se = float(named_forms[0].values[2]), float(named_forms[0].stderr[2])
        p_g = float(2 * stats.norm.sf(abs(g - 1.0) / max(se, 1e-300)))
        ag.update({"scan_gain": g, "scan_gain_stderr": se, "p": p_g, "agree": rules.datum_agrees(p_g),
                   "fitted_with": [c.label for c in v.best.fit.components]})
    if not ag["agree"]:
        if v.cause in ("none", "plane_form"):
            confidence = "low"  # the inputs contradict each other on the datum
        summary += DATUM_DISAGREES.format(p=ag["p"])
    return replace(b.datum, against_readings=ag), confidence, summary


def _steps_table(b: BaseAnalysis, steps, v: Verdict) -> list:
    """The residuals after each step: per sensor in-sample RMS and held-out RMS (mm), and
    whether the cause it added is named in the verdict ``v`` (a step's cause can be turned down
    after the selection: not needed given the others, crosstalk, its sensors not explained)."""
    out = [{"added": None, "model": "base", "residual_rms_mm": np.sqrt(np.nanmean(b.fit.residual**2, axis=0)).tolist(),
            "heldout_rms_mm": b.heldout.rms()}]
    labels, named = [], {c.label for c in v.causes}
    for st in steps:
        if st.chosen is None:
            break
        labels.append(st.chosen.label)
        out.append({"added": st.chosen.label, "model": "base + " + " + ".join(labels),
                    "residual_rms_mm": np.sqrt(np.nanmean(st.chosen.fit.residual**2, axis=0)).tolist(),
                    "heldout_rms_mm": st.chosen.heldout.rms(), "p_heldout": st.chosen.p_heldout,
                    "heldout_gain_chi2": st.chosen.heldout_chi2_reduction, "named": st.chosen.label in named})
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
    rng = np.random.default_rng(seed)
    notify(progress, 0, 5, "base model and its held-out figures")
    b = base_analysis(ds, folds)
    flags, p_out = flag_outliers(ds.layout, ds.obs, b.cov, b.sigma, b.theta0)
    steps = forward_select(ds, b, flags, p_out, folds, on_candidate=lambda k, i, n, label: notify(
        progress, 1, 5, f"selection step {k}: candidate {i + 1}/{n} ({label})"))
    chosen = [st.chosen for st in steps if st.chosen is not None]
    notify(progress, 2, 5, "verdict and the causes' gains")
    v = verdict(ds, b, steps, folds, rng)
    if v.dropped is not None:  # nothing named: the sole cause chosen is not in the model
        chosen = []
    rand = v.random_pose  # a random pose error predicts no reading: not in the model
    fitted = [s for s in chosen if not (rand and s.component.per_pose)]  # joint model, last step's held-out
    joint = replace(fitted[-1], fit=v.best.fit, label="+".join(s.label for s in fitted)) if fitted else (
        replace(v.best, heldout=b.heldout) if rand else None)
    named_flags = flags_of(chosen)
    notify(progress, 3, 5, "side-by-side simulation")
    discrepancy, heldout = side_by_side(ds, b, joint, named_flags, folds, sim_reps, rng)
    confidence = v.confidence
    summary = verdict_summary(v, b.tests)
    scored = steps[0].scored
    datum = b.datum
    if datum is not None:
        notify(progress, 4, 5, "datum check")
        datum, confidence, summary = check_datum(ds, b, v, chosen, scored, confidence, summary)
    notify(progress, 5, 5, "done")
    gross = np.zeros(ds.obs.d.shape, bool) if named_flags is None else named_flags  # left out of the held-out RMS

    def held(ho):
        return None if ho is None else np.where(gross, np.nan, ho.residual)

    plot = PlotData(b.fit, b.cov, b.d0, v.best, ds.layout.names, b.sigma, flags if named_flags is None else named_flags,
                    b.structure, held(b.heldout), held(None if joint is None else joint.heldout))
    return Diagnosis(v.cause, v.sensors, confidence, summary, v.named, tuple(scored), b.tests, v.tests_extended,
                     b.structure, discrepancy, heldout, v.confounding, b.fit.theta, b.fit.theta_stderr,
                     dict(THRESHOLDS), datum, plot, v.causes, tuple(_steps_table(b, steps, v)),
                     detectable_sizes(steps[0].scored, b, np.isfinite(ds.obs.d).sum(axis=0), ds))

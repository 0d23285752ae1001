"""The diagnosis: the base model's discrepancy, the candidates, the decision, the gain.

:func:`diagnose` is a sequence of named steps (see :mod:`metrology.diagnosis` for the
procedure): :func:`base_analysis`, :func:`score_candidates`, :func:`choose`, :func:`verdict`,
:func:`side_by_side`, :func:`check_datum`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from metrology.core.effects import VERDICTS, ExtendedModel, PlaneForm
from metrology.core.layout import SensorLayout
from metrology.core.model import readings
from metrology.diagnosis.candidates import (CandidateResult, candidates_for, covariates_for, flag_outliers,
                                            score_candidate)
from metrology.diagnosis.datum import DatumFormCheck, datum_form, form_agreement
from metrology.diagnosis.extension import describe_named, dof_per_sensor, simulated_figures
from metrology.diagnosis.fit import Fit, fit_any, geometry
from metrology.diagnosis.heldout import HeldOut, kfold
from metrology.diagnosis.stats import NoiseTests, battery_on, noise_tests, structure
from metrology.diagnosis.summary import DATUM_DISAGREES, verdict_summary
from metrology.diagnosis.thresholds import ADVICE, THRESHOLDS

__all__ = ["Diagnosis", "PlotData", "BaseAnalysis", "Verdict", "diagnose", "base_analysis", "score_candidates",
           "choose", "verdict", "side_by_side", "check_datum"]


@dataclass(frozen=True)
class PlotData:
    """What the residual plots of :func:`metrology.report.diagnose.plot_report` draw.

    base : Fit; cov : Covariates; d0 : (p, n) float, mm, the base readings; best : the named
    (or partial) CandidateResult or None; names : tuple of str; sigma : (n,) float, mm;
    flags : (p, n) bool, flagged readings; structure : dict, the base structure table
    """

    base: Fit
    cov: object
    d0: np.ndarray
    best: CandidateResult | None
    names: tuple
    sigma: np.ndarray
    flags: np.ndarray
    structure: dict


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_dict` is the ``--json`` output.

    ``candidates`` are the scored candidates, largest held-out gain first; ``tests_base`` and
    ``tests_extended`` the noise-model battery before and after the extension;
    ``datum_form`` the datum check (None without a datum cloud); ``plot_data`` what the plots draw.
    """

    cause: str
    sensors: list
    confidence: str
    summary: str
    named: dict | None
    candidates: tuple
    tests_base: NoiseTests
    tests_extended: NoiseTests | None
    structure_base: dict
    discrepancy: dict
    heldout: dict
    confounding: list
    base_theta: np.ndarray
    base_stderr: np.ndarray
    thresholds: dict
    datum_form: DatumFormCheck | None = None
    plot_data: PlotData | None = None

    def to_dict(self):
        return {
            "cause": self.cause, "sensors": self.sensors, "confidence": self.confidence, "summary": self.summary,
            "extended": self.named, "heldout": self.heldout, "discrepancy": self.discrepancy,
            "candidates": [c.to_dict() for c in self.candidates], "confounding": self.confounding,
            "tests": {"base": self.tests_base.to_dict(),
                      "extended": None if self.tests_extended is None else self.tests_extended.to_dict()},
            "structure": self.structure_base,
            "base": {"theta": self.base_theta.tolist(), "stderr": self.base_stderr.tolist(),
                     "columns": ["dx_mm", "dy_mm", "dz_mm", "a_rad", "b_rad"]},
            "thresholds": self.thresholds,
            "datum_form": None if self.datum_form is None else self.datum_form.to_dict(),
        }


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
    """Steps 3-4: the cause, its sensors and confidence, the named candidate (refitted by
    ``lsq``, or None), the noise tests after the extension, the confounding notes and the
    named component's description."""

    cause: str
    sensors: list
    confidence: str
    best: CandidateResult | None
    tests_extended: NoiseTests | None
    confounding: list
    named: dict | None


def base_analysis(ds, folds) -> BaseAnalysis:
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
    tests = noise_tests(base.residual, sigma, dof_base, names)
    struct = structure(base.residual, d0, cov, names)
    ho_base = kfold(nominal, obs, cov, sigma, (), folds, theta0)
    datum = None if ds.datum_points is None else datum_form(ds, zero, u, obs, cov, d0, sigma)
    return BaseAnalysis(sigma, cov, calibrated, theta0, base, d0, tests, struct, ho_base, datum)


def score_candidates(ds, b: BaseAnalysis, folds):
    """Step 2: flag gross readings, build every catalogued candidate and score it.
    Returns (list of CandidateResult in candidate order, flags (p, n) bool)."""
    nominal, obs = ds.layout, ds.obs
    flags, p_out = flag_outliers(nominal, obs, b.cov, b.sigma, b.theta0)
    cands = candidates_for(nominal, b.cov, flags)
    scored = [score_candidate(c, nominal, obs, b.cov, b.sigma, b.fit, b.heldout, flags, p_out, folds, b.theta0,
                              len(cands)) for c in cands]
    return scored, flags


def _p_separation(other: CandidateResult, best: CandidateResult) -> float:
    """One-sided paired test that ``best``'s per-pose held-out chi-square is below ``other``'s."""
    from scipy import stats

    d = other.chi2_pose - best.chi2_pose
    return float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue) if not np.allclose(d, 0) else 1.0


def choose(scored):
    """The significant candidates, largest held-out gain first (a time drift yields to the
    temperature drift of the same sensors when the data cannot tell them apart), and the
    lead: the strongest candidate significant in sample only. Returns (sig_list, lead)."""
    n_cand = len(scored)
    sig_list = sorted([s for s in scored if s.significant], key=lambda s: -s.heldout_chi2_reduction)
    # the strongest candidate significant in sample only: a lead, never a name
    in_only = sorted([s for s in scored if not s.significant and s.p_insample < THRESHOLDS["alpha_candidates"] / n_cand],
                     key=lambda s: s.p_insample)
    lead = in_only[0] if in_only else None
    best = sig_list[0] if sig_list else None
    if best is not None and best.cause == "drift" and best.component.variable == "time":
        # tie-break: temperature is the physical cause, time its proxy; prefer it when the
        # data cannot tell the two apart
        for other in sig_list[1:]:
            oc = other.component
            if oc.name == "drift" and oc.variable == "temp" and oc.sensors == best.component.sensors:
                if _p_separation(other, best) >= THRESHOLDS["alpha_confound"]:
                    sig_list.remove(other)
                    sig_list.insert(0, other)
                break
    return sig_list, lead


def _confounding(best: CandidateResult, sig_list) -> list:
    """Runner-ups that explain as much (a different cause or sensor), and parameters of the
    named component too correlated with the base geometry."""
    out = []
    for other in sig_list[1:]:
        if other.cause == best.cause and other.sensors == best.sensors:
            continue
        p_sep = _p_separation(other, best)
        if p_sep >= THRESHOLDS["alpha_confound"]:
            out.append({
                "between": [best.label, other.label], "p_separation": p_sep,
                "message": f"the data cannot tell {best.label} from {other.label} (held-out gains "
                           f"indistinguishable, p = {p_sep:.2g}); to separate them: "
                           f"{ADVICE[best.cause]}; {ADVICE[other.cause]}",
            })
    f = best.fit
    fc = f.components[0]
    for q, (cb_, w) in enumerate(zip(f.corr_base, f.corr_with)):
        if cb_ > THRESHOLDS["corr_confound"]:
            out.append({
                "between": [f"{fc.label}.{fc.param_names[q]}", w], "correlation": float(cb_),
                "message": f"{fc.label}.{fc.param_names[q]} is {cb_:.3f} correlated with the base parameter "
                           f"{w}: it is poorly separated from the geometry; {ADVICE[fc.name]} would separate them",
            })
    return out


def verdict(ds, b: BaseAnalysis, sig_list, lead, rng) -> Verdict:
    """Steps 3-4: name the best significant candidate if its sensors' residuals become
    consistent with noise, re-identify it (``lsq``) and describe it with its confounding."""
    nominal, obs = ds.layout, ds.obs
    n = obs.d.shape[1]
    best = sig_list[0] if sig_list else None
    if best is None:
        cause = "none" if b.tests.consistent else "unexplained"
        confidence = "high" if b.tests.consistent and lead is None else "low"
        return Verdict(cause, [], confidence, None, None, [], None)
    f = fit_any(nominal, obs, b.cov, b.sigma, (best.component,), b.theta0, "lsq")
    best = replace(best, fit=f)
    # a per-pose component makes the sensors of a pose correlated by construction
    tests_ext = noise_tests(f.residual, b.sigma, dof_per_sensor(f, obs, n), nominal.names,
                            pairs=not any(c.per_pose for c in f.components))
    p_concerned = battery_on(tests_ext, list(f.sensors))
    tests_ext = replace(tests_ext, p_concerned=p_concerned)
    if p_concerned >= THRESHOLDS["alpha_battery"]:
        cause, sensors = best.cause, best.sensors
        # its own sensors are explained; others that still fail are a separate matter
        confidence = "high" if tests_ext.consistent else "partial"
    else:
        cause, confidence, sensors = "unexplained", "low", []
    confounding = _confounding(best, sig_list)
    if confounding and confidence == "high":
        confidence = "ambiguous"
    named = describe_named(f, nominal, obs, b.cov, b.sigma, rng)
    return Verdict(cause, sensors, confidence, best, tests_ext, confounding, named)


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
    excl = flags if best.cause == "outliers" else None
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


def check_datum(ds, b: BaseAnalysis, v: Verdict, scored, confidence, summary):
    """The readings' own form against the datum cloud's. Returns (datum check with
    ``against_readings``, confidence, summary), lowered and extended when they disagree."""
    # plane_form fitted together with the named cause (a pose error, say, correlates the
    # sensors of a pose; a form fitted without it would carry standard errors too small for
    # the comparison)
    if v.cause == "plane_form":
        pf = v.best.fit
    elif v.cause in VERDICTS:  # nothing named: the plane_form candidate's own fit
        pf = next(s.fit for s in scored if s.cause == "plane_form")
    else:
        comps = [PlaneForm((), names=ds.layout.names), replace(v.best.component, values=None, stderr=None)]
        pf = fit_any(ds.layout, ds.obs, b.cov, b.sigma, comps, b.theta0)
    ag = form_agreement(b.datum, pf)
    ag["fitted_with"] = [c.label for c in pf.components]
    if not ag["agree"]:
        if v.cause in ("none", "plane_form"):
            confidence = "low"  # the inputs contradict each other on the datum
        summary += DATUM_DISAGREES.format(p=ag["p"])
    return replace(b.datum, against_readings=ag), confidence, summary


def diagnose(ds, folds: int = 5, sim_reps: int = 2, seed: int = 0) -> Diagnosis:
    """Run the full diagnosis on a :class:`~metrology.calibration.dataset.Dataset` (see
    :mod:`metrology.diagnosis`).

    ``folds``: k of the k-fold by pose; ``sim_reps``: simulated copies of the data set per
    side-by-side figure; ``seed``: of the simulation's noise (the diagnosis itself is
    deterministic).
    """
    p = ds.obs.d.shape[0]
    if p < 2 * folds:
        raise ValueError(f"{p} poses: need at least {2 * folds} for {folds}-fold held-out figures")
    rng = np.random.default_rng(seed)
    b = base_analysis(ds, folds)
    scored, flags = score_candidates(ds, b, folds)
    sig_list, lead = choose(scored)
    v = verdict(ds, b, sig_list, lead, rng)
    if v.best is not None:  # the named candidate carries its lsq refit from here on
        scored = [v.best if s is sig_list[0] else s for s in scored]
    discrepancy, heldout = side_by_side(ds, b, v.best, flags, folds, sim_reps, rng)
    confidence = v.confidence
    summary = verdict_summary(v.cause, confidence, v.best, b.tests, v.tests_extended, lead)
    datum = b.datum
    if datum is not None:
        datum, confidence, summary = check_datum(ds, b, v, scored, confidence, summary)
    ranked = tuple(sorted(scored, key=lambda s: -s.heldout_chi2_reduction))
    plot = PlotData(b.fit, b.cov, b.d0, v.best, ds.layout.names, b.sigma, flags, b.structure)
    return Diagnosis(v.cause, v.sensors, confidence, summary, v.named, ranked, b.tests, v.tests_extended, b.structure,
                     discrepancy, heldout, v.confounding, b.fit.theta, b.fit.theta_stderr, dict(THRESHOLDS), datum, plot)

"""The decision: discrepancy, candidates, confounding, extension and gain, as one :class:`Diagnosis`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import numpy as np
from metrology.core.effects import VERDICTS, ExtendedModel, Outliers, PlaneForm
from metrology.core.observations import Observations
from metrology.core.model import readings
from metrology.diagnosis.candidates import ADVICE, candidates_for, covariates_for
from metrology.diagnosis.datum import DatumCheck, datum_form, form_agreement
from metrology.diagnosis.fit import Fit, fit_model, _geometry, fit
from metrology.diagnosis.heldout import HeldOut, kfold
from metrology.diagnosis.stats import THRESHOLDS, NoiseTests, battery_on, noise_tests, structure
from metrology.diagnosis.summary import _describe_named, _summary




@dataclass(frozen=True)
class Candidate:
    """One candidate component scored against the base model.

    Attributes
    ----------
    score : dict
        The public result (``--json``'s ``candidates`` entry: p-values, held-out chi-square
        reduction, RMS and normal deviation, ``significant``); read as ``candidate[key]``.
    fit : Fit
        The extended fit on all poses.
    heldout : HeldOut
        Its k-fold held-out predictions.
    component : Component
        The fitted component.
    chi2_pose : (p,) float
        Held-out chi-square per pose, all sensors (the ranking between candidates).
    """

    score: dict
    fit: Fit
    heldout: HeldOut
    component: object
    chi2_pose: np.ndarray

    def __getitem__(self, key):
        return self.score[key]

    def to_dict(self) -> dict:
        return dict(self.score)


@dataclass(frozen=True)
class PlotData:
    """What the figures of :mod:`metrology.report.diagnose` draw: the base fit, the covariates,
    the base readings ``d0 : (p, n) float, mm``, the named candidate (or None), sensor names,
    stated noise ``sigma : (n,) float, mm``, gross-reading flags and the structure table."""

    base: Fit
    cov: object
    d0: np.ndarray
    best: Candidate | None
    names: tuple
    sigma: np.ndarray
    flags: np.ndarray | None
    structure: dict


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_dict` is the ``--json`` output."""

    cause: str
    sensors: list
    confidence: str
    summary: str
    named: dict | None
    candidates: list
    tests_base: NoiseTests
    tests_extended: NoiseTests | None
    structure_base: dict
    discrepancy: dict
    heldout: dict
    confounding: list
    base_theta: np.ndarray
    base_stderr: np.ndarray
    thresholds: dict
    datum_form: DatumCheck | None = None
    # for the figures
    plot_data: PlotData | None = field(default=None, repr=False)

    def to_dict(self):
        return {
            "cause": self.cause, "sensors": self.sensors, "confidence": self.confidence, "summary": self.summary,
            "extended": self.named, "heldout": self.heldout, "discrepancy": self.discrepancy,
            "candidates": self.candidates, "confounding": self.confounding,
            "tests": {"base": self.tests_base.to_dict(),
                      "extended": None if self.tests_extended is None else self.tests_extended.to_dict()},
            "structure": self.structure_base,
            "base": {"theta": self.base_theta.tolist(), "stderr": self.base_stderr.tolist(),
                     "columns": ["dx_mm", "dy_mm", "dz_mm", "a_rad", "b_rad"]},
            "thresholds": self.thresholds,
            "datum_form": None if self.datum_form is None else self.datum_form.to_dict(),
        }


def _flag_outliers(nominal, obs, cov, sigma, theta0):
    """Robust per-sensor fit; flag |r| / s > t with t at ``alpha_outlier`` family-wise.

    ``s`` is the larger of the stated noise and the residuals' robust (MAD) scale. Returns
    (flags (p, n) bool, p-value of the largest standardised residual).
    """
    from scipy import stats

    p, n = obs.d.shape
    m = int(np.isfinite(obs.d).sum())
    z = np.full((p, n), np.nan)
    for i in range(n):
        f = fit(nominal, obs, cov, sigma, (), sensors=[i], theta0=theta0, loss="soft_l1", solver="gn")
        r = f.residual[:, i]
        mad = 1.4826 * np.nanmedian(np.abs(r - np.nanmedian(r)))
        z[:, i] = r / max(sigma[i], mad)
    zmax = float(np.nanmax(np.abs(z)))
    p_max = min(1.0, m * 2 * float(stats.norm.sf(zmax)))
    t = float(stats.norm.isf(THRESHOLDS["alpha_outlier"] / (2 * m)))
    flags = np.isfinite(z) & (np.abs(z) > t)
    return flags, p_max


def _simulated_figures(nominal, obs, cov, sigma, model: ExtendedModel, k, theta0, rng, reps, per_pose_sigma=None):
    """Simulation of this data set under ``model`` plus the stated noise, analysed with the
    base model: in-sample residual RMS per sensor (n,) mm and held-out normal deviation mean
    (rad), averaged over ``reps`` draws."""
    d_model = model.predict(obs.normal, obs.offset, cov)
    rms, ndev = [], []
    for _ in range(reps):
        d = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
        d = np.where(np.isfinite(obs.d), d, np.nan)
        o = Observations(obs.normal, obs.offset, d)
        b = fit_model(nominal, o, cov, sigma, (), theta0)
        rms.append(np.sqrt(np.nanmean(b.residual**2, axis=0)))
        ndev.append(np.nanmean(kfold(nominal, o, cov, sigma, (), k, theta0).normal_dev))
    return np.mean(rms, axis=0), float(np.mean(ndev)), float(np.std(ndev))


def _dof_per_sensor(f: Fit, obs, n):
    cnt = np.isfinite(obs.d).sum(axis=0).astype(float)
    dof = cnt - 5
    for c in f.components:
        if c.sensors:
            for i in c.sensors:
                dof[i] -= c.n_params / len(c.sensors)
        else:
            dof -= (c.n_params - (3 if c.per_pose else len(c.constraint(c.values)[0]))) / n
    return dof


def diagnose(ds, folds: int = 5, sim_reps: int = 2, seed: int = 0) -> Diagnosis:
    """Run the full diagnosis on a :class:`~metrology.dataset.Dataset` (see the module doc).

    ``folds``: k of the k-fold by pose; ``sim_reps``: simulated copies of the data set per
    side-by-side figure; ``seed``: of the simulation's noise (the diagnosis itself is
    deterministic).
    """
    from scipy import stats

    nominal = ds.layout
    obs = ds.obs
    p, n = obs.d.shape
    if p < 2 * folds:
        raise ValueError(f"{p} poses: need at least {2 * folds} for {folds}-fold held-out figures")
    names = nominal.names
    sigma = nominal.noise_mm.copy()
    rng = np.random.default_rng(seed)
    # 1. base calibration (per sensor) with covariates at the nominal geometry, then recomputed
    cov0 = covariates_for(ds, nominal)
    sig_fit = np.where(np.isfinite(sigma), sigma, 1.0)
    base0 = fit_model(nominal, obs, cov0, sig_fit, (), None, "lsq")
    if not np.all(np.isfinite(sigma)):  # no stated noise: the base fit's own scatter
        sigma = np.where(np.isfinite(sigma), sigma, np.sqrt(np.nanmean(base0.residual**2, axis=0)))
    zero, u = _geometry(nominal, base0.theta)
    calibrated = nominal.with_params(zero, u)
    cov = covariates_for(ds, calibrated)
    theta0 = base0.theta
    base = fit_model(nominal, obs, cov, sigma, (), theta0, "lsq")
    d0_base = readings(zero, u, obs.normal, obs.offset)[0]
    dof_base = np.isfinite(obs.d).sum(axis=0) - 5
    tests_base = noise_tests(base.residual, sigma, dof_base, names)
    struct = structure(base.residual, d0_base, cov, names)
    ho_base = kfold(nominal, obs, cov, sigma, (), folds, theta0)
    datum = None if ds.datum_points is None else datum_form(ds, zero, u, obs, cov, d0_base, sigma)

    # 2. candidates
    flags, p_out = _flag_outliers(nominal, obs, cov, sigma, theta0)
    cands = candidates_for(nominal, cov, flags)
    n_cand = len(cands)
    scored = []
    for c in cands:
        f = fit_model(nominal, obs, cov, sigma, (c,), theta0)
        k = c.n_params - (3 if c.per_pose else len(c.constraint(c.values)[0]))
        S = list(f.sensors)
        chi2_b = float(np.nansum((base.residual[:, S] / sigma[S]) ** 2))
        chi2_e = float(np.nansum((f.residual[:, S] / sigma[S]) ** 2))
        m_S = int(np.isfinite(obs.d[:, S]).sum())
        dof_e = m_S - 5 * len(S) - k
        if isinstance(c, Outliers):
            p_in = p_out  # selection by the largest residual: its own test
        else:
            F = ((chi2_b - chi2_e) / k) / max(chi2_e / max(dof_e, 1), 1e-300)
            p_in = float(stats.f.sf(F, k, max(dof_e, 1)))
        ho = kfold(nominal, obs, cov, sigma, (c,), folds, theta0)
        excl = flags if isinstance(c, Outliers) else None
        cb = ho_base.chi2_pose(sigma, exclude=excl)
        ce = ho.chi2_pose(sigma, exclude=excl)
        diff = cb - ce  # all sensors: comparable between candidates (ranking)
        diff_S = ho_base.chi2_pose(sigma, S, excl) - ho.chi2_pose(sigma, S, excl)  # its sensors: the test
        if np.allclose(diff_S, 0):
            p_ho = 1.0
        else:
            p_ho = float(stats.ttest_1samp(diff_S, 0.0, alternative="greater").pvalue)
        rb, re_ = ho_base.rms(S, excl), ho.rms(S, excl)
        nb_, ne_ = float(np.nanmean(ho_base.normal_dev)), float(np.nanmean(ho.normal_dev))
        sig = (p_in < THRESHOLDS["alpha_candidates"] / n_cand) and (p_ho < THRESHOLDS["alpha_heldout"]) and rb > re_
        scored.append(Candidate({
            "label": c.label, "cause": c.name, "sensors": [names[i] for i in c.sensors], "n_params": k,
            "p_insample": p_in, "p_heldout": p_ho, "heldout_chi2_reduction": float(np.sum(diff)),
            "heldout_rms_base_mm": rb, "heldout_rms_extended_mm": re_, "heldout_rms_ratio": rb / re_,
            "heldout_normal_base_deg": float(np.rad2deg(nb_)), "heldout_normal_extended_deg": float(np.rad2deg(ne_)),
            "significant": bool(sig)}, f, ho, c, ce))
    sig_list = sorted([s for s in scored if s["significant"]], key=lambda s: -s["heldout_chi2_reduction"])
    # the strongest candidate significant in sample only: a lead, never a name
    in_only = sorted([s for s in scored if not s["significant"] and s["p_insample"] < THRESHOLDS["alpha_candidates"] / n_cand],
                     key=lambda s: s["p_insample"])
    lead = in_only[0] if in_only else None

    # decision
    named = None
    tests_ext = None
    confounding = []
    best = sig_list[0] if sig_list else None
    if best is not None and best["cause"] == "drift" and best.component.variable == "time":
        # tie-break: temperature is the physical cause, time its proxy; prefer it when the
        # data cannot tell the two apart
        for other in sig_list[1:]:
            oc = other.component
            if oc.name == "drift" and oc.variable == "temp" and oc.sensors == best.component.sensors:
                d = other.chi2_pose - best.chi2_pose
                p_sep = float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue) if not np.allclose(d, 0) else 1.0
                if p_sep >= THRESHOLDS["alpha_confound"]:
                    sig_list.remove(other)
                    sig_list.insert(0, other)
                    best = other
                break
    if best is None:
        cause = "none" if tests_base["consistent"] else "unexplained"
        confidence = "high" if tests_base["consistent"] and lead is None else "low"
        sensors = []
    else:
        best = replace(best, fit=fit_model(nominal, obs, cov, sigma, (best.component,), theta0, "lsq"))
        f = best.fit
        # a per-pose component makes the sensors of a pose correlated by construction
        tests_ext = noise_tests(f.residual, sigma, _dof_per_sensor(f, obs, n), names,
                                pairs=not any(c.per_pose for c in f.components))
        concerned = list(f.sensors)
        p_concerned = battery_on(tests_ext, concerned)
        tests_ext.summary["p_concerned"] = p_concerned
        if p_concerned >= THRESHOLDS["alpha_battery"]:
            cause, sensors = best["cause"], best["sensors"]
            # its own sensors are explained; others that still fail are a separate matter
            confidence = "high" if tests_ext["consistent"] else "partial"
        else:
            cause, confidence = "unexplained", "low"
            sensors = []
        # runner-ups that explain as much (a different cause or sensor)
        for other in sig_list[1:]:
            if other["cause"] == best["cause"] and other["sensors"] == best["sensors"]:
                continue
            d = other.chi2_pose - best.chi2_pose
            p_sep = float(stats.ttest_1samp(d, 0.0, alternative="greater").pvalue) if not np.allclose(d, 0) else 1.0
            if p_sep >= THRESHOLDS["alpha_confound"]:
                confounding.append({
                    "between": [best["label"], other["label"]], "p_separation": p_sep,
                    "message": f"the data cannot tell {best['label']} from {other['label']} (held-out gains "
                               f"indistinguishable, p = {p_sep:.2g}); to separate them: "
                               f"{ADVICE[best['cause']]}; {ADVICE[other['cause']]}",
                })
        fc = f.components[0]
        for q, (cb_, w) in enumerate(zip(f.corr_base, f.corr_with)):
            if cb_ > THRESHOLDS["corr_confound"]:
                confounding.append({
                    "between": [f"{fc.label}.{fc.param_names[q]}", w], "correlation": float(cb_),
                    "message": f"{fc.label}.{fc.param_names[q]} is {cb_:.3f} correlated with the base parameter "
                               f"{w}: it is poorly separated from the geometry; {ADVICE[fc.name]} would separate them",
                })
        if confounding and confidence == "high":
            confidence = "ambiguous"
        named = _describe_named(best, f, nominal, obs, cov, sigma, rng)

    # 3-4. side by side and held-out gains
    base_model = ExtendedModel(calibrated, ())
    sim_rms_b, sim_nd_b, sim_nd_b_sd = _simulated_figures(nominal, obs, cov, sigma, base_model, folds, theta0, rng, sim_reps)
    meas_rms = np.sqrt(np.nanmean(base.residual**2, axis=0))
    discrepancy = {
        "sensors": list(names),
        "stated_noise_mm": sigma.tolist(),
        "measured_residual_rms_mm": meas_rms.tolist(),
        "simulated_base_residual_rms_mm": sim_rms_b.tolist(),
        "measured_heldout_normal_deg": float(np.rad2deg(np.nanmean(ho_base.normal_dev))),
        "simulated_base_heldout_normal_deg": float(np.rad2deg(sim_nd_b)),
        "simulated_base_heldout_normal_sd_deg": float(np.rad2deg(sim_nd_b_sd)),
        "sim_reps": sim_reps,
    }
    heldout = {"folds": folds, "base_rms_mm": ho_base.rms(), "base_normal_deg": float(np.rad2deg(np.nanmean(ho_base.normal_dev)))}
    if best is not None:
        fm = best.fit.model(nominal)
        sim_rms_e, sim_nd_e, sim_nd_e_sd = _simulated_figures(nominal, obs, cov, sigma, fm, folds, theta0, rng, sim_reps)
        discrepancy["simulated_extended_residual_rms_mm"] = sim_rms_e.tolist()
        discrepancy["simulated_extended_heldout_normal_deg"] = float(np.rad2deg(sim_nd_e))
        discrepancy["simulated_extended_heldout_normal_sd_deg"] = float(np.rad2deg(sim_nd_e_sd))
        discrepancy["extended_model"] = best["label"]
        ho_e = best.heldout
        excl = flags if best["cause"] == "outliers" else None
        S = list(best.fit.sensors)
        heldout.update({
            "model": best["label"],
            "base_rms_mm": ho_base.rms(None, excl), "extended_rms_mm": ho_e.rms(None, excl),
            "rms_ratio": ho_base.rms(None, excl) / ho_e.rms(None, excl),
            "base_rms_concerned_mm": ho_base.rms(S, excl), "extended_rms_concerned_mm": ho_e.rms(S, excl),
            "rms_ratio_concerned": ho_base.rms(S, excl) / ho_e.rms(S, excl),
            "extended_normal_deg": float(np.rad2deg(np.nanmean(ho_e.normal_dev))),
            "normal_ratio": float(np.nanmean(ho_base.normal_dev) / np.nanmean(ho_e.normal_dev)),
            "p_heldout": best["p_heldout"],
        })
    summary = _summary(cause, confidence, best, tests_base, tests_ext, lead)
    if datum is not None:
        # the readings' own form against the cloud's: plane_form fitted together with the named
        # cause (a pose error, say, correlates the sensors of a pose; a form fitted without it
        # would carry standard errors too small for the comparison)
        if cause == "plane_form":
            pf = best.fit
        elif cause in VERDICTS:  # nothing named: the plane_form candidate's own fit
            pf = next(s.fit for s in scored if s["cause"] == "plane_form")
        else:
            comps = [PlaneForm((), names=names), replace(best.component, values=None, stderr=None)]
            pf = fit_model(nominal, obs, cov, sigma, comps, theta0)
        datum.summary["against_readings"] = form_agreement(datum, pf)
        datum.summary["against_readings"]["fitted_with"] = [c.label for c in pf.components]
        if not datum["against_readings"]["agree"]:
            if cause in ("none", "plane_form"):
                confidence = "low"  # the inputs contradict each other on the datum
            summary += (f"; the datum cloud's form disagrees with the readings' (p = {datum['against_readings']['p']:.2g}): "
                        "the datum changed between scan and run, or the cloud is not of the surface the beams saw")
    public = [s.to_dict() for s in scored]
    public.sort(key=lambda s: -s["heldout_chi2_reduction"])
    plot = PlotData(base, cov, d0_base, best, names, sigma, flags, struct)
    return Diagnosis(cause, sensors, confidence, summary, named, public, tests_base, tests_ext, struct, discrepancy,
                     heldout, confounding, base.theta, base.theta_stderr, dict(THRESHOLDS), datum, plot)

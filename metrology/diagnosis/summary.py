"""The verdict in words: the named cause, its size, and what to do."""

from __future__ import annotations

from dataclasses import replace
import numpy as np
from metrology.core.effects import Outliers, PoseError
from metrology.core.observations import Observations
from metrology.diagnosis.fit import Fit, fit


#: simulated noise-only copies used to measure the noise floor of the per-pose estimates
POSE_FLOOR_REPS = 8


def _describe_named(best, f: Fit, nominal, obs, cov, sigma, rng):
    comp = f.components[0]
    d = comp.describe()
    if isinstance(comp, PoseError):
        # sigma of the pose error along the normal: the spread of the per-pose estimates less
        # the spread that reading noise alone puts in them (through the per-pose fit and the
        # base parameters it trades with), measured on noise-only simulations of these poses
        e = comp.values
        model = replace(f.model(nominal), components=())
        d_model = model.predict(obs.normal, obs.offset, cov)

        def estimate(e_sim):
            """sigma-hat of noise-only copies (the floor) or copies with per-pose errors ``e_sim``."""
            vals = []
            for _ in range(POSE_FLOOR_REPS):
                dn = d_model + rng.normal(0.0, 1.0, d_model.shape) * sigma[None, :]
                if e_sim is not None:
                    dn = dn + rng.normal(0.0, e_sim, len(dn))[:, None] * cov.inv_nu
                dn = np.where(np.isfinite(obs.d), dn, np.nan)
                fn = fit(nominal, Observations(obs.normal, obs.offset, dn), cov, sigma, [replace(comp, values=None)],
                         theta0=f.theta, solver="gn")
                vals.append(np.var(fn.components[0].values, ddof=1))
            return np.array(vals)

        v_floor = float(np.mean(estimate(None)))
        sig_raw = np.sqrt(max(float(np.var(e, ddof=1)) - v_floor, 0.0))
        # parametric bootstrap: the spread of the per-pose estimates also takes up weakly
        # identified base-parameter combinations; re-estimate on copies with pose errors of the
        # estimated size, correct the bias and take their scatter as the standard error
        boot = np.sqrt(np.maximum(estimate(sig_raw) - v_floor, 0.0))
        sig_e = max(sig_raw - (float(np.mean(boot)) - sig_raw), 0.0)
        d["params"] = {"sigma_mm": {"value": sig_e, "unit": "mm", "stderr": float(np.std(boot, ddof=1))},
                       "noise_floor_mm": {"value": float(np.sqrt(v_floor)), "unit": "mm", "stderr": None}}
        d["per_pose_mm"] = e.tolist()
    if isinstance(comp, Outliers):
        d["flagged"] = [{"pose": int(pp), "sensor": comp.names[i], "gross_mm": float(v), "stderr": float(s)}
                        for (pp, i), v, s in zip(comp.cells, comp.values, comp.stderr)]
        d["params"] = {"count": {"value": len(comp.cells), "unit": "1", "stderr": None}}
    d["base_correlation"] = [{"param": comp.param_names[q], "max_abs_corr": float(c), "with": w}
                             for q, (c, w) in enumerate(zip(f.corr_base, f.corr_with))]
    return d


def _summary(cause, confidence, best, tb, te, in_only=None):
    """One paragraph of the verdict; ``in_only`` is the strongest candidate significant in
    sample only (its held-out gain not), reported as a lead when nothing is named."""
    worst = max(tb["sensors"].items(), key=lambda kv: kv[1]["chi2"] / kv[1]["dof"])
    lead = ""
    if in_only is not None:
        lead = (f"; {in_only['label']} fits in sample (p = {in_only['p_insample']:.2g}) but does not predict held-out "
                f"poses significantly better (p = {in_only['p_heldout']:.2g}, RMS ratio "
                f"{in_only['heldout_rms_ratio']:.3g}): too small, or too confounded, to name")
    if cause == "none":
        return (f"residuals consistent with the stated noise (battery p = {tb['p_bonferroni']:.2g}); "
                "no candidate gives a significant held-out gain" + lead)
    if best is None:
        return (f"residuals inconsistent with the noise model (battery p = {tb['p_bonferroni']:.2g}, worst "
                f"{worst[0]}: sigma {worst[1]['sigma_est_mm']:.4g} mm) and no catalogued effect gives a "
                "significant held-out gain" + lead)
    if cause == "unexplained":
        return (f"{best['label']} gives a significant held-out gain (RMS ratio {best['heldout_rms_ratio']:.3g}) but "
                f"leaves the residuals of its sensors inconsistent with the noise model (battery p = "
                f"{te['p_concerned']:.2g}): a partial explanation at best")
    text = (f"{best['label']}: held-out RMS ratio {best['heldout_rms_ratio']:.3g} on its sensors (p = "
            f"{best['p_heldout']:.2g}), its sensors' residuals then consistent with noise (p = {te['p_concerned']:.2g})")
    if not te["consistent"]:
        text += (f"; other residuals remain inconsistent (battery p = {te['p_bonferroni']:.2g}): another effect, "
                 "or a false alarm of the tests")
    return text + f"; confidence {confidence}"

"""The verdict in one paragraph (part of the result: the ``summary`` of the ``--json`` output)."""

from __future__ import annotations

from metrology.core.effects import REGISTRY
from metrology.diagnosis.select import weakly_supported
from metrology.diagnosis.stats import battery_on
from metrology.diagnosis import rules
from metrology.diagnosis.thresholds import THRESHOLDS

__all__ = ["verdict_summary", "DATUM_DISAGREES"]

#: appended to the summary when the datum cloud's form disagrees with the readings'
DATUM_DISAGREES = ("; the datum cloud's form disagrees with the readings' (p = {p:.2g}): "
                   "the datum changed between scan and run, or the cloud is not of the surface the beams saw")


def _lead_text(in_only) -> str:
    if in_only is None:
        return ""
    return (f"; {in_only.label} fits in sample (p = {in_only.p_insample:.2g}) but does not predict held-out "
            f"poses significantly better (p = {in_only.p_heldout:.2g}, RMS ratio "
            f"{in_only.heldout_rms_ratio:.3g}): too small, or too confounded, to name")


def verdict_summary(v, tb) -> str:
    """One paragraph of the verdict ``v`` (:class:`~metrology.diagnosis.decide.Verdict`);
    ``tb`` the noise tests on the base residuals. Several causes are named together, and
    structure that remains beside them is said."""
    worst = max(tb.sensors.items(), key=lambda kv: kv[1]["chi2"] / kv[1]["dof"])
    lead = _lead_text(v.lead)
    te = v.tests_extended
    consistent = f"residuals consistent with the stated noise (battery p = {tb.p_bonferroni:.2g})"
    inconsistent = (f"residuals inconsistent with the noise model (battery p = {tb.p_bonferroni:.2g}, worst "
                    f"{worst[0]}: sigma {worst[1]['sigma_est_mm']:.4g} mm)")
    nothing_above = "no effect above the detectable sizes (smaller ones are not ruled out)"
    if v.dropped is not None:
        dr = v.dropped
        turned = (f"{dr['label']} was selected (held-out p = {dr['p_step']:.2g} at its step) but is not needed against "
                  f"the base model (held-out chi-square gain {dr['gain_chi2']:.3g}, p = {dr['p_base']:.2g}), so it is not "
                  "named")
        if v.cause == "none":
            return f"{consistent}; {turned}: {nothing_above}" + lead
        return f"{inconsistent}; {turned}: no catalogued cause explains the structure" + lead
    if v.cause == "none":
        return f"{consistent}; no candidate gives a significant held-out gain: {nothing_above}" + lead
    if v.best is None:
        return (f"{inconsistent} and no catalogued effect gives a significant held-out gain: structure outside the "
                "catalogue" + lead)
    better = next((r for r in v.rivals if r.better), None)
    if v.cause == "unexplained" and better is not None:
        return (f"{v.best.label} gives a significant held-out gain, but {better.label} (crosstalk: predicts held-out "
                f"poses better than {better.of}, p = {better.p:.2g}): the effect follows another "
                "sensor's distance, which is outside the catalogue (crosstalk between sensors, a shared supply)")
    if v.cause == "unexplained":
        return (f"{v.best.label} gives a significant held-out gain (RMS ratio {v.best.heldout_rms_ratio:.3g}) but "
                f"leaves the residuals of its sensors inconsistent with the noise model (battery p = "
                f"{te.p_concerned:.2g}): a partial explanation at best; structure outside the catalogue remains")
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
        where = where or [max(te.sensors.items(), key=lambda kv: kv[1]["chi2"] / kv[1]["dof"])[0]]
        text += (f"; structure remains on {', '.join(where)} (battery p = {te.p_bonferroni:.2g}): another effect, "
                 "or a false alarm of the tests")
    ties = [r for r in v.rivals if not r.better]
    if ties and v.confidence == "ambiguous":
        of = list(dict.fromkeys(r.of for r in ties))
        return text + ("; confidence ambiguous: " + "; ".join(
            f"{', '.join(r.label for r in ties if r.of == o)} (a shift in proportion to another sensor's distance, "
            f"crosstalk, outside the catalogue) predicts held-out poses as well as {o}" for o in of)
            + f"; poses that separate them: {', '.join(dict.fromkeys(r.separate for r in ties))}")
    weak = weakly_supported(v.causes) if v.confidence == "moderate" else []
    if weak:
        p = {c.label: c.p_heldout_given_others for c in v.causes}
        return text + (f"; confidence moderate: weak held-out evidence for "
                       f"{' and '.join(f'{k} (p = {p[k]:.2g})' for k in weak)}, not below {THRESHOLDS['alpha_high']:g}")
    return text + f"; confidence {v.confidence}"

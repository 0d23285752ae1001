"""The verdict in one paragraph (part of the result: the ``summary`` of the ``--json`` output), made
from the judgement's trail of reasons (:class:`~metrology.diagnosis.results.Reason`), never re-derived."""

from __future__ import annotations

from metrology.core.effects import REGISTRY
from metrology.diagnosis.results import Confidence, Decision, Outcome, Reason
from metrology.diagnosis.stats import battery_on
from metrology.diagnosis import rules

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


def _last(reasons, decided: Decision) -> Reason | None:
    return next((r for r in reversed(reasons) if r.decided == decided), None)


def verdict_summary(v, tb) -> str:
    """One paragraph of the judgement ``v`` (:class:`~metrology.diagnosis.judge.Judgement`), made
    from its trail ``v.reasons`` (which rule decided, on what, with which figures) and the causes
    it named; ``tb`` the noise tests on the base residuals. Several causes are named together,
    and structure that remains beside them is said."""
    why = v.reasons
    worst = max(tb.sensors.items(), key=lambda kv: kv[1]["chi2"] / kv[1]["dof"])
    lead = _lead_text(v.lead) if _last(why, Decision.LEAD) is not None else ""
    te = v.tests_extended
    consistent = f"residuals consistent with the stated noise (battery p = {tb.p_bonferroni:.2g})"
    inconsistent = (f"residuals inconsistent with the noise model (battery p = {tb.p_bonferroni:.2g}, worst "
                    f"{worst[0]}: sigma {worst[1]['sigma_est_mm']:.4g} mm)")
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
        where = where or [max(te.sensors.items(), key=lambda kv: kv[1]["chi2"] / kv[1]["dof"])[0]]
        text += (f"; structure remains on {', '.join(where)} (battery p = {te.p_bonferroni:.2g}): another effect, "
                 "or a false alarm of the tests")
    confidence = _last(why, Decision.CONFIDENCE).outcome  # rule 16's (before the datum's, rule 17)
    named = {c.label for c in v.causes}
    ties = [r for r in why if r.decided == Decision.CROSSTALK_TIE and r.concerns[0] in named]
    if ties and confidence == Confidence.AMBIGUOUS:
        return text + ("; confidence ambiguous: " + "; ".join(
            f"{', '.join(r.concerns[1:])} (a shift in proportion to another sensor's distance, "
            f"crosstalk, outside the catalogue) predicts held-out poses as well as {r.concerns[0]}" for r in ties)
            + f"; poses that separate them: {', '.join(dict.fromkeys(r.outcome for r in ties))}") + tail
    weak = [r for r in why if r.decided == Decision.WEAK] if confidence == Confidence.MODERATE else []
    if weak:
        return text + (f"; confidence moderate: weak held-out evidence for "
                       f"{' and '.join(f'{r.concerns[0]} (p = {r.value:.2g})' for r in weak)}, not below "
                       f"{weak[0].threshold:g}") + tail
    return text + f"; confidence {confidence}" + tail

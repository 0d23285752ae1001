"""The verdict in one paragraph (part of the result: the ``summary`` of the ``--json`` output)."""

from __future__ import annotations

__all__ = ["verdict_summary", "DATUM_DISAGREES"]

#: appended to the summary when the datum cloud's form disagrees with the readings'
DATUM_DISAGREES = ("; the datum cloud's form disagrees with the readings' (p = {p:.2g}): "
                   "the datum changed between scan and run, or the cloud is not of the surface the beams saw")


def verdict_summary(cause, confidence, best, tb, te, in_only=None) -> str:
    """One paragraph of the verdict; ``best`` the named (or partial) candidate, ``tb``/``te`` the
    noise tests before/after the extension; ``in_only`` is the strongest candidate significant in
    sample only (its held-out gain not), reported as a lead when nothing is named."""
    worst = max(tb.sensors.items(), key=lambda kv: kv[1]["chi2"] / kv[1]["dof"])
    lead = ""
    if in_only is not None:
        lead = (f"; {in_only.label} fits in sample (p = {in_only.p_insample:.2g}) but does not predict held-out "
                f"poses significantly better (p = {in_only.p_heldout:.2g}, RMS ratio "
                f"{in_only.heldout_rms_ratio:.3g}): too small, or too confounded, to name")
    if cause == "none":
        return (f"residuals consistent with the stated noise (battery p = {tb.p_bonferroni:.2g}); "
                "no candidate gives a significant held-out gain" + lead)
    if best is None:
        return (f"residuals inconsistent with the noise model (battery p = {tb.p_bonferroni:.2g}, worst "
                f"{worst[0]}: sigma {worst[1]['sigma_est_mm']:.4g} mm) and no catalogued effect gives a "
                "significant held-out gain" + lead)
    if cause == "unexplained":
        return (f"{best.label} gives a significant held-out gain (RMS ratio {best.heldout_rms_ratio:.3g}) but "
                f"leaves the residuals of its sensors inconsistent with the noise model (battery p = "
                f"{te.p_concerned:.2g}): a partial explanation at best")
    text = (f"{best.label}: held-out RMS ratio {best.heldout_rms_ratio:.3g} on its sensors (p = "
            f"{best.p_heldout:.2g}), its sensors' residuals then consistent with noise (p = {te.p_concerned:.2g})")
    if not te.consistent:
        text += (f"; other residuals remain inconsistent (battery p = {te.p_bonferroni:.2g}): another effect, "
                 "or a false alarm of the tests")
    return text + f"; confidence {confidence}"

"""Each command's verdict as data (:class:`metrology.core.verdict.Verdict`) and its words.

A check's name says what it judges, before the colon: ``drilling tolerance``, ``model
adequacy``, ``precision target``, ``flatness tolerance``, ``form``, ``scan``. A check the user
set a limit for (a tolerance, a target) gates the exit code; a limit the user did not set
(a default target, a statistical test of the model) is information (``gate=False``).

The calibration's checks are built by :meth:`metrology.calibration.calibrate.CalibrationReport.verdict`;
the others here, from the result objects the jobs return. ``diagnosis_verdict`` is the one
place that reads a :class:`~metrology.diagnosis.Diagnosis` for its exit code.
"""

from __future__ import annotations

import math

from metrology.core.tolerances import DRILLING_TOLERANCE_DEG
from metrology.core.verdict import Check, Verdict

__all__ = ["plane_verdict", "validation_checks", "diagnosis_verdict", "normals_verdict", "steps_verdict",
           "check_words", "verdict_text", "verdict_word", "NO_VERDICT", "NO_VERDICT_LINE"]

#: a command that judges nothing (version, simulate, reproduce, plan): passed, no checks
NO_VERDICT = Verdict(())
#: the verdict line of a command that judges nothing (it writes data: simulate, simulate-log, reproduce)
NO_VERDICT_LINE = "verdict: passed (exit code 0): nothing judged (simulated data written)"

#: fit-plane: below this share of inliers the scan holds more than the datum (information)
SCAN_INLIER_SHARE = 0.9


def _f(x) -> float:
    return float(x) if x is not None and math.isfinite(float(x)) else float("nan")


def plane_verdict(fit, flatness_mm: float | None = None) -> Verdict:
    """``fit-plane``: flatness (P-V) against ``flatness_mm`` when the user gave one (gates);
    the form test and the inlier share are information."""
    d = fit.to_dict()
    checks = []
    if flatness_mm is not None:
        checks.append(Check("flatness tolerance: P-V of the inliers", d["flatness_mm"], float(flatness_mm), "mm",
                            d["flatness_mm"] <= flatness_mm))
    form = d["form"]
    if form is not None:
        checks.append(Check("form: p-value of the quadratic form (F-test; significant below alpha)",
                            _f(form["p_value"]), float(form["alpha"]), "", not form["significant"], gate=False,
                            at_least=True))
    checks.append(Check("scan: share of inliers", d["inlier_ratio"], SCAN_INLIER_SHARE, "",
                        d["inlier_ratio"] >= SCAN_INLIER_SHARE, gate=False, at_least=True))
    return Verdict(tuple(checks))


def validation_checks(v: dict) -> Verdict:
    """``validate``: the validated layout's largest deviation against the drilling tolerance
    (gates; the tolerance has a default, the paper's 0.5 deg requirement, and is a tolerance,
    not a precision target); ``v`` is :func:`metrology.report.validation.validation_verdict`."""
    return Verdict((Check("drilling tolerance: max normal deviation", v["max_deg"], v["tolerance_deg"], "deg", v["ok"]),
                    Check("mean normal deviation", v["mean_deg"], None, "deg", True, gate=False)))


def diagnosis_verdict(diag, tolerance_deg: float = DRILLING_TOLERANCE_DEG, fail_on_cause: bool = False) -> Verdict:
    """``diagnose``: the held-out normal deviation against the drilling tolerance (gates), and
    the cause found (gates only under ``--fail-on-cause``: a named cause, ``unexplained``
    included; ``none`` passes). Reads only ``diag.to_dict()``'s ``cause`` and
    ``discrepancy.measured_heldout_normal_deg``."""
    D = diag.to_dict()
    held = _f(D["discrepancy"]["measured_heldout_normal_deg"])
    cause = str(D["cause"])
    n_causes = 0 if cause == "none" else max(1, len(D.get("causes") or ()))
    return Verdict((Check("drilling tolerance: held-out normal deviation", held, float(tolerance_deg), "deg",
                          bool(held <= tolerance_deg)),
                    Check(f"cause found: {cause}", n_causes, 0, "causes", cause == "none", gate=fail_on_cause)))


def normals_verdict(summary: dict, tolerance_deg: float) -> Verdict:
    """``normals``: the recommended method's largest first-measurement error against the
    tolerance (gates); after the attitude loop, its largest remaining deviation (gates); the
    other method's error is information."""
    rec = summary["recommendation"]["method"]
    checks = []
    for name in ("plane", "sphere"):
        s = summary[name]
        mx = _f(s["max_deg"])
        gate = name == rec
        checks.append(Check(f"drilling tolerance: micro-{name} max normal error" + ("" if gate else " (not recommended)"),
                            mx, float(tolerance_deg), "deg", bool(mx <= tolerance_deg), gate=gate))
        if gate and "final_max_deg" in s:
            fm = _f(s["final_max_deg"])
            checks.append(Check(f"drilling tolerance: micro-{name} max attitude deviation after the loop", fm,
                                float(tolerance_deg), "deg", bool(fm <= tolerance_deg)))
    if rec is None:
        checks.append(Check("points measured", 0, 1, "points", False))
    return Verdict(tuple(checks))


def steps_verdict(steps) -> Verdict:
    """``demo``: one check per step, its exit code (0 passed, 1 its verdict failed)."""
    return Verdict(tuple(Check(f"step {name}: exit code", int(rc), 0, "", int(rc) == 0) for name, rc in steps))


def _num(x, unit) -> str:
    if x is None:
        return "—"
    if isinstance(x, int):
        return f"{x}{' ' + unit if unit else ''}"
    x = float(x)
    if not math.isfinite(x):
        return "—"
    return f"{x:.4g}{' ' + unit if unit else ''}"


def check_words(c: Check) -> tuple[str, str]:
    """(tag, sentence) of a check: tag ``pass``, ``FAIL``, ``info`` (information, within its
    limit) or ``note`` (information, beyond its limit)."""
    tag = ("pass" if c.passed else "FAIL") if c.gate else ("info" if c.passed else "note")
    if c.limit is None:
        return tag, f"{c.name}: {_num(c.value, c.unit)}"
    op = ("≥" if c.passed else "<") if c.at_least else ("≤" if c.passed else ">")
    extra = "" if c.gate else " (information)"
    return tag, f"{c.name}: {_num(c.value, c.unit)} {op} {_num(c.limit, c.unit)}{extra}"


def verdict_word(verdict: Verdict) -> str:
    """The verdict's one word, in the terminal and in the HTML alike: ``FAILED`` (a check that
    gates failed: exit code 1), ``passed`` (every check that gates passed) or ``information``
    (no check gates: nothing was judged against a limit the user set; exit code 0)."""
    if not verdict.passed:
        return "FAILED"
    return "passed" if any(c.gate for c in verdict.checks) else "information"


def verdict_text(verdict: Verdict) -> str:
    """The verdict as lines: ``verdict: passed`` / ``FAILED`` / ``information``
    (:func:`verdict_word`) with the exit code, then one line per check."""
    if not verdict.checks:
        return ""
    lines = [f"verdict: {verdict_word(verdict)} (exit code {0 if verdict.passed else 1})"]
    for c in verdict.checks:
        tag, words = check_words(c)
        lines.append(f"  [{tag}] {words}")
    return "\n".join(lines)

"""The HTML report's section of each command: its verdict, figures, numbers with their
uncertainties and units, what the data could not determine and what to do next
(:class:`metrology.report.html.Section`)."""

from __future__ import annotations

import math
import shlex
from pathlib import Path

import numpy as np

from metrology.core.tolerances import CORRELATION_REPORT, DRILLING_TOLERANCE_DEG
from metrology.report.html import Section, Table, figure_from_matplotlib, verdict_box

__all__ = ["plane_section", "calibration_section", "validation_section", "diagnosis_section", "normals_section"]


#: "±" between spaces: on a narrow page a cell breaks there rather than inside a number
_PM = " ± "


def _pm(v, se, unit, digits=4):
    return f"{v:.{digits}f}{_PM}{se:.{digits}f} {unit}".strip() if se is not None and np.isfinite(se) else f"{v:.{digits}f} {unit}"


def _num(v, missing="—", digits=4):
    return f"{v:.{digits}f}" if v is not None and np.isfinite(v) else missing


def plane_section(fit, points, flatness_mm: float | None = None) -> Section:
    """``metro fit-plane``: the datum plane, described by what was found (no flatness
    tolerance is stated, so none is judged): flat within the noise, a form detected (a
    significant quadratic form, its P-V in µm), or a scan that holds more than the datum.
    With ``flatness_mm`` (``--flatness-mm``) the P-V is judged against it."""
    from metrology.report.datum import format_plane_fit, residual_map_figure
    from metrology.report.verdicts import plane_verdict

    d = fit.to_dict()
    form = d["form"]
    ratio = d["inlier_ratio"]
    bowed = form is not None and form["significant"]
    if bowed:
        label = f"form detected: {1e3 * form['pv_mm']:.1f} µm P-V"
    elif ratio < 0.9:
        label = f"scan not only the datum: {100 * ratio:.1f} % inliers"
    elif form is None:
        label = "form not tested: too few inliers"
    else:
        label = "flat within the noise"
    head = (f"datum plane of {Path(d['source']).name}: RMS {d['rms_mm']:.4f} mm, flatness (P-V) "
            f"{d['flatness_mm']:.4f} mm over {d['n_inliers']} of {d['n_points']} points")
    if bowed:
        cause = (f"the datum is not flat: a quadratic form of P-V {form['pv_mm']:.4f} mm is significant "
                 f"(p = {form['p_value']:.2g}); every calibration on it inherits that form")
    elif ratio < 0.9:
        cause = f"only {100 * ratio:.1f} % of the points are inliers: the scan holds something other than the datum"
    elif form is None:
        cause = "too few inliers to test the form"
    else:
        cause = f"no significant form (p = {form['p_value']:.2g}): flat within the tracker noise"
    rows = [("normal (A, B, C)", " ".join(f"{x:.8f}" for x in d["normal"]),
             "—" if d["normal_sigma_deg"] is None else f"{d['normal_sigma_deg']:.3g} deg", "1"),
            ("offset D", f"{d['offset']:.5f}", "—" if d["offset_sigma_mm"] is None else f"{d['offset_sigma_mm']:.3g}", "mm"),
            ("noise σ", f"{d['noise_sigma_mm']:.5f}" if d["noise_sigma_mm"] is not None else "—", "", "mm"),
            ("RMS of the inliers", f"{d['rms_mm']:.5f}", "", "mm"),
            ("flatness (P-V)", f"{d['flatness_mm']:.5f}", "", "mm"),
            ("inliers", f"{d['n_inliers']} of {d['n_points']}", "", f"within {d['threshold_mm']:.4g} mm")]
    if form is not None:
        rows.append(("quadratic form P-V", f"{form['pv_mm']:.5f}", f"p = {form['p_value']:.2g}", "mm"))
    nxt, limits = [], []
    if bowed:
        nxt.append("Re-measure the datum (clean, re-clamp, re-scan), or calibrate with the form modelled: "
                   "`metro diagnose` names a plane_form from the readings and checks it against this scan.")
    if ratio < 0.9:
        nxt.append("Crop the scan to the datum face, or check the outliers on the map (grey ×).")
    if form is not None and not bowed:
        limits.append(f"a form below the test's reach (F-test at alpha {form['alpha']:g}; P-V of the fitted form "
                      f"{form['pv_mm']:.4f} mm) is not ruled out")
    limits.append("the plane is in the tracker frame: its link to the robot (the poses) is not checked here")
    fig = residual_map_figure(points, fit)
    return Section("Datum plane (metro fit-plane)", verdict_box(plane_verdict(fit, flatness_mm), head, cause, label),
                   figures=(figure_from_matplotlib(fig, "Residual to the fitted plane over the plate (inliers coloured, "
                                                   "outliers grey ×; contours: the fitted quadratic form, dotted when not "
                                                   "significant)."),),
                   tables=(Table("Plane and its uncertainty (1 σ)", ("quantity", "value", "1 σ", "unit"), tuple(rows)),),
                   text=(format_plane_fit(fit),), limits=tuple(limits), next_steps=tuple(nxt))


def _diagnose_command(sources) -> str:
    if not all(k in sources for k in ("export", "plane", "layout")):
        return "metro diagnose EXPORT --plane PLANE --layout LAYOUT"
    return shlex.join(["metro", "diagnose", sources["export"], "--plane", sources["plane"], "--layout",
                       sources["layout"], "--report", "diagnose.html"])


def calibration_section(report) -> Section:
    """``metro calibrate``: residuals against the stated noise, precision against the target,
    the lmfit-style fit report per sensor, convergence and residual figures."""
    from metrology.calibration.identifiability import sigma_words
    from metrology.report.calibration import (calibration_warnings, convergence_figure, fit_summaries, noise_advice,
                                              precision_advice, residuals_figure)
    from metrology.report.fit_report import fit_report

    d = report.to_dict()
    fits = fit_summaries(report)
    noise = noise_advice(report)
    precision = precision_advice(report)
    worst = max(d["sensors"], key=lambda s: s["residual_rms_mm"] / s["noise_mm"] if s["noise_mm"] > 0 else 0)
    head = (f"{d['method']} on {d['n_poses']} poses: residual RMS up to {1e3 * worst['residual_rms_mm']:.1f} µm "
            f"({worst['name']}) against a stated noise of {1e3 * worst['noise_mm']:.1f} µm")
    causes = []
    if noise:
        causes.append("model adequacy: the residuals exceed the stated noise: the model misses something (or the noise "
                      "is understated)")
    if precision:
        causes.append(precision[0])
    if not causes:
        causes.append("residuals consistent with the stated noise and every parameter within the precision target")
    nxt = []
    if noise:
        nxt.append(f"Run `{_diagnose_command(report.sources)}` to name what the model misses.")
    nxt += [line.strip() for line in precision[1:]]
    limits = [d["unidentified"]] + list(calibration_warnings(report))
    for ident in report.identifiability:
        limits.append(f"{ident.name}: least determined: {ident.words[-1]} (1 σ {sigma_words(ident.combination_sigma[-1])})")
    rows = []
    for fit in fits:
        for name, value, se, rel, unit in fit.param_rows():
            rows.append((fit.sensor, name, value, se, rel, unit))
    stats = tuple((f.sensor, str(f.ndata), str(f.nvarys), f"{f.chisqr:.4g}", f"{f.redchi:.3g}") for f in fits)
    correl = tuple((f.sensor, f"C({a}, {b})", f"{r:+.3f}") for f in fits for a, b, r in f.correl_above())
    tables = (Table("Fit statistics per sensor (χ² against the stated noise)",
                    ("sensor", "data points", "variables", "χ²", "reduced χ²"), stats),
              Table("Parameters: error of the nominal, 1 σ and relative error", ("sensor", "parameter", "value", "1 σ",
                                                                                 "relative", "unit"), tuple(rows)),
              Table(f"Correlations with |r| > {CORRELATION_REPORT:g}", ("sensor", "pair", "r"), correl,
                    "The pairs of x, y, tilt_e1, tilt_e2 move together when the beam pivots about a point along it "
                    "(see what the data could not determine)."))
    conv = ("The filter's estimate after each measurement (dotted: its stopping rule met); dm, dn, dq are "
            "changes of the unit beam direction's components." if report.calibration.history else
            "Estimate from the first k poses (±1 σ bands): flat means the poses determine the parameter.")
    figs = (figure_from_matplotlib(convergence_figure(report), conv),
            figure_from_matplotlib(residuals_figure(report), "Reading residuals of the calibrated layout against the "
                                   "reading, the incidence angle and the pose: a trend is a missing effect."))
    return Section("Sensor calibration (metro calibrate)", verdict_box(report.verdict(), head, "; ".join(causes)),
                   figures=figs,
                   tables=tables, text=tuple(fit_report(f) for f in fits), limits=tuple(limits), next_steps=tuple(nxt))


def validation_section(report, tolerance_deg: float = DRILLING_TOLERANCE_DEG) -> Section:
    """``metro validate``: the validated layout's largest deviation against the tolerance."""
    from metrology.report.validation import layout_words, left_out, validation_figure, validation_verdict
    from metrology.report.verdicts import validation_checks

    v = validation_verdict(report, tolerance_deg)
    who = layout_words(report, v["label"])
    head = (f"{who}: largest deviation {v['max_deg']:.4f} deg against a tolerance of {tolerance_deg:g} deg "
            f"(mean {v['mean_deg']:.4f} ± {v['mean_stderr_deg']:.4f} deg over {v['n_poses']} poses)")
    cause = (f"margin ×{v['margin']:.3g} below the tolerance" if v["ok"] else
             f"{int(np.sum(np.rad2deg(report.deviation[-1]) > tolerance_deg))} pose(s) over the tolerance")
    if v["improvement"] is not None:
        cause += f"; mean deviation {v['improvement']:.3g} times smaller than {layout_words(report, report.labels[0])}"
    rows = []
    for k, lab in enumerate(report.labels):
        s = report.stats_deg(k)
        se = s["std_deg"] / math.sqrt(s["n_poses"]) if s["n_poses"] > 1 else float("nan")
        rows.append((layout_words(report, lab), f"{s['max_deg']:.4f}", _pm(s["mean_deg"], se, ""), f"{s['std_deg']:.4f}",
                     str(s["n_poses"])))
    gone = left_out(report)
    limits = []
    if gone:
        limits.append(f"pose(s) {', '.join(gone)}: fewer than 3 readings, no normal; left out of the statistics")
    limits.append("the deviation tests the measured normal as a whole, not each sensor's parameters")
    nxt = []
    if not v["ok"]:
        nxt.append("Run `metro diagnose` on the calibration export to name what the model misses, then re-calibrate.")
    if gone:
        nxt.append(f"Re-measure pose(s) {', '.join(gone)} with every beam on the datum.")
    fig = validation_figure(report, tolerance_deg)
    return Section("Validation on held-out poses (metro validate)", verdict_box(validation_checks(v), head, cause),
                   figures=(figure_from_matplotlib(fig, "Deviation of the measured normal from the datum normal per pose "
                                                   "(log axis), dashed: the tolerance."),),
                   tables=(Table("Deviation of the measured normal [deg]; mean ± 1 σ of the mean",
                                 ("layout", "max", "mean", "std", "poses"), tuple(rows)),),
                   limits=tuple(limits), next_steps=tuple(nxt))


def diagnosis_section(diag, tolerance_deg: float = DRILLING_TOLERANCE_DEG) -> Section:
    """``metro diagnose``: the held-out normal deviation against the drilling tolerance, the
    cause named, the extension's fit report."""
    from metrology.diagnosis.thresholds import ADVICE
    from metrology.report.diagnose import (GRID_MAX_VARIABLES, UNEXPLAINED_NEXT, detectable_words, diagnosis_figures,
                                           report_text, structure_level, structure_rows)
    from metrology.report.verdicts import diagnosis_verdict

    D = diag.to_dict()
    cause = D["cause"]
    held = D["discrepancy"]["measured_heldout_normal_deg"]
    verdict = diagnosis_verdict(diag, tolerance_deg)
    ok = verdict.passed
    who = f" on {', '.join(D['sensors'])}" if D["sensors"] else ""
    head = (f"held-out normal deviation {held:.5f} deg against a tolerance of {tolerance_deg:g} deg; "
            f"confidence in the cause: {D['confidence']}")
    label = f"cause: {cause}{who}; normal {'within' if ok else 'NOT within'} tolerance ({held:.4f} vs {tolerance_deg:g} deg)"
    nxt, limits = [], []
    for c in D["causes"]:
        adv = ADVICE.get(c["cause"])
        if adv:
            nxt.append(f"{c['cause']}: {adv}")
    if cause == "unexplained":
        nxt += list(UNEXPLAINED_NEXT)
        limits.append("the residuals are not consistent with the stated noise, and no catalogued effect explains them")
    if cause == "none":
        limits.append("no effect above the detectable sizes; smaller ones are not ruled out")
    if D.get("detectable"):
        limits.append("detectable at 95 % power on these poses: " + detectable_words(D))
    limits += [c["message"] for c in D["confounding"]]
    tables = []
    disc = D["discrepancy"]
    rows = [("stated noise", *(f"{1e3 * v:.2f}" for v in disc["stated_noise_mm"]), "")]
    rows.append(("measured", *(f"{1e3 * v:.2f}" for v in disc["measured_residual_rms_mm"]),
                 f"{disc['measured_heldout_normal_deg']:.5f}"))
    rows.append(("simulation, base model", *(f"{1e3 * v:.2f}" for v in disc["simulated_base_residual_rms_mm"]),
                 f"{disc['simulated_base_heldout_normal_deg']:.5f}"))
    if "simulated_extended_residual_rms_mm" in disc:
        rows.append((f"simulation, + {disc['extended_model']}",
                     *(f"{1e3 * v:.2f}" for v in disc["simulated_extended_residual_rms_mm"]),
                     f"{disc['simulated_extended_heldout_normal_deg']:.5f}"))
    tables.append(Table("Residual RMS per sensor [µm] and held-out normal deviation [deg]",
                        ("", *(f"{n} [µm]" for n in disc["sensors"]), "normal [deg]"), tuple(rows)))
    level = structure_level(diag.structure_base)
    tables.append(Table("Structure of the base residuals: R² of a quadratic trend against each variable",
                        ("variable", *disc["sensors"]), structure_rows(diag),
                        f"*: carries structure, its F-test's p below {level:.2g} (the battery's level split over the "
                        f"table's cells). The first figure draws the variables (at most {GRID_MAX_VARIABLES}, the most "
                        "structured first) and the sensors of these cells, each with its p; none when no cell carries "
                        "structure. Every p is in the --json output (structure)."))
    text = []
    fit = extension_fit_summary(diag)
    if fit is not None:
        from metrology.report.fit_report import fit_report

        text.append(fit_report(fit))
    text.append(report_text(diag))
    figs = tuple(figure_from_matplotlib(f, cap) for _, f, cap in diagnosis_figures(diag))
    return Section("Diagnosis: what the base model misses (metro diagnose)", verdict_box(verdict, head, D["summary"], label),
                   figures=figs, tables=tuple(tables), text=tuple(text), limits=tuple(limits), next_steps=tuple(nxt))


def extension_fit_summary(diag):
    """A :class:`~metrology.report.fit_report.FitSummary` of the named extension's parameters
    (the joint fit of every cause), or None when nothing was named."""
    from metrology.report.fit_report import FitSummary, correlations_from_cov

    P = diag.plot_data
    if P is None or P.best is None or not diag.causes:
        return None
    f = P.best.fit
    params, names = [], []
    for c in diag.causes:
        for k, v in c.params.items():
            params.append((k, float(v.value), None if v.stderr is None else float(v.stderr), v.unit))
            names.append(k)
    # the readings of the fitted sensors, and what the fit's dof leaves of them (held base
    # parameters and per-pose values counted as the fit counted them)
    ndata = int(np.isfinite(f.residual[:, list(f.sensors)]).sum())
    nvarys = ndata - int(f.dof)
    corr = ()
    if f.extra_cov.shape == (len(names), len(names)):
        corr = correlations_from_cov(f.extra_cov, names)
    corr += tuple((n, w, float(r)) for n, w, r in zip(names, f.corr_with, f.corr_base) if w)
    return FitSummary(f"base + {' + '.join(c.label for c in diag.causes)}", "lsq", ndata, nvarys,
                      float(f.chi2), tuple(params), corr)


def normals_section(summary: dict, fig, tolerance_deg: float) -> Section:
    """``metro normals``: the recommended method's errors against the tolerance; ``fig`` the
    error map (:func:`metrology.report.normals.error_map_figure`, or None); every fact of the
    text output (:func:`metrology.report.normals.summary_text`) is on the page."""
    from metrology.panel.attitude import STATUS
    from metrology.report.normals import summary_text
    from metrology.report.verdicts import normals_verdict

    rec = summary["recommendation"]
    m = rec["method"]
    s = summary[m]
    verdict = normals_verdict(summary, tolerance_deg)
    head = (f"micro-{m}: {100 * s['within_tolerance']:.1f} % of {s['n']} points within {tolerance_deg:g} deg "
            f"(max {s['max_deg']:.4f}, 95th percentile {s['p95_deg']:.4f} deg)")
    rows = []
    for name in ("plane", "sphere"):
        t = summary[name]
        rows.append((f"micro-{name}", str(t["n"]), f"{t['max_deg']:.4f}", f"{t['mean_deg']:.4f}{_PM}{t['std_deg']:.4f}",
                     f"{t['p95_deg']:.4f}", f"{100 * t['within_tolerance']:.1f} %",
                     _num(t.get("final_max_deg"), "— (no loop)")))
    bad = {k: v for k, v in summary["status"].items() if k != "ok" and v}
    limits = [f"{v} point(s) not measured: {STATUS[k]}" for k, v in bad.items()]
    if summary.get("grid_dropped"):
        limits.append(f"grid: {summary['grid_dropped']} nodes left out: the head's footprint would cross a crease, "
                      "a hole or the panel boundary")
    limits += list(summary.get("warnings", ()))
    info = summary["info"]
    limits.append(f"units: {info['units']}")
    nxt = []
    if bad or summary.get("grid_dropped"):
        nxt.append("Move the points not measured away from the panel's edges, or use a shorter stand-off.")
    if not verdict.passed:
        nxt.append("Calibrate the head (`metro calibrate`) and check it with `metro validate` before drilling.")
    nxt.append(f"Use micro-{m} on this panel (the recommendation below).")
    marks = "grey ×: not measured." if bad else "every point was measured."
    figs = () if fig is None else (figure_from_matplotlib(fig, "Normal error over the panel, each method on its own "
                                                          f"colour scale; open red circles: over the tolerance; {marks}"),)
    return Section("Normals on the panel (metro normals)", verdict_box(verdict, head, rec["text"]), figures=figs,
                   tables=(Table("Normal error of the first measurement [deg] (mean ± std over the points)",
                                 ("method", "points", "max", "mean ± std", "p95", "within tol.", "after loop, max"),
                                 tuple(rows), f"engine {info['engine']}, stand-off {info['standoff_mm']:.3f} mm, "
                                 f"tilt {info['tilt_deg']:g} deg, reference normal: {info['reference_normal']}"),),
                   text=(summary_text(summary),), limits=tuple(limits), next_steps=tuple(nxt))

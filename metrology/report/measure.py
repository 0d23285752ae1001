"""Words and figures of ``metro measure``: the text report and the HTML section."""

from __future__ import annotations

import datetime as _dt

import numpy as np

from metrology.io.names import utc  # its public name here stays

__all__ = ["measure_text", "measure_section", "utc"]

_MAX_GROUP_ROWS = 40


def _when(t_s: float) -> str:
    """UTC of seconds since the epoch as two words, date and time (a table's cell may break
    between them on a phone; the header says UTC)."""
    return _dt.datetime.fromtimestamp(float(t_s), _dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")


def _judged(report) -> str:
    s = report.result.summary
    if s.judged_after and not s.judged_before:
        return "the angle after the attitude adjustment (the drilled hole's)"
    if s.judged_before and not s.judged_after:
        return "the angle measured before any adjustment (the log has no after-readings)"
    return (f"the angle after the adjustment where the hole has after-readings ({s.judged_after:,} holes), "
            f"else before it ({s.judged_before:,})")


def _alarm_words(a) -> str:
    shifts = ", ".join(f"{k} {v:+.1f} µm" for k, v in a.sensor_shift_um.items())
    return (f"cell {a.cell!r}, panel {a.panel!r}: alarm at hole {a.hole_id} ({utc(a.time_s)}); the redundant "
            f"reading's misfit ran {a.run_um:+.1f} µm off its level over the {a.holes_since_start} holes from hole "
            f"{a.start_hole_id} ({utc(a.start_time_s)}); its level "
            + (f"moved {a.size_um:+.1f} µm and stayed; a zero shift of one sensor alone: {shifts} (one redundant "
               f"reading cannot tell which of the 4)" if a.persisted else
               f"then returned ({a.size_um:+.2f} µm)") + f": {a.advice}")  # the advice says whether it persisted


def _ppk(fig, short: bool = False) -> str:
    """The judged angle's Ppk (``fig``: :class:`~metrology.measure.tally.Figures`) with its 95 % interval, or why
    there is none."""
    p = float("nan") if fig.ppk is None else fig.ppk
    if not np.isfinite(p):
        from metrology.measure.summary import MIN_PPK_HOLES

        return "-" if short else f"Ppk - (fewer than {MIN_PPK_HOLES:,} holes)"
    lo, hi = fig.ppk_ci95
    return f"{p:.3g} [{lo:.3g}, {hi:.3g}]" if short else f"Ppk {p:.3g} (95 % CI {lo:.3g} to {hi:.3g})"


def _q(fig, which: str, key: str) -> str:
    v = getattr(getattr(fig, f"quantiles_{which}_deg"), key)
    return "-" if not np.isfinite(v) else f"{v:.4g}"


def _spin_words(cv) -> str:
    """How U95 took the head's spin where the log has no pose: the convention's bound, every spin, or both (a
    3-sensor log without the pose is judged over every spin: the bound alone would misstate it)."""
    conv = f"the head's spin +-{cv.spin_deg:g} deg where the log has no pose"
    if not cv.spin_free_holes:
        return conv
    every = f"a U95 over every spin for the {cv.spin_free_holes:,} holes whose spin is not known"
    return f"{conv}, {every}" if cv.spin_on_convention_holes else every


def _panel_terms(report) -> str:
    """What of the panel U95 carries: its known surface's terms, or the curvature bound."""
    cv = report.curvature
    if cv.known:  # each hole's surface known (--panel/--points)
        return (f" + each hole's curvature from {cv.source} (its fit; the drill point's position error "
                f"{cv.position_error_mm:g} mm; the form tolerance {cv.form_tolerance_mm:g} mm; {_spin_words(cv)})")
    return (f" + the micro-plane's curvature bias for a panel radius >= {report.min_radius_mm:g} mm (and where a "
            f"4-sensor misfit beyond the noise lies within that bound, one sensor's offset it cannot be told from: "
            f"rule 2b, docs/gross.md)")


def _limits(report) -> list:
    """What the data could not determine, for the run's panel: known (its CAD) or bounded."""
    cv = report.curvature
    if cv.known:
        panel = [f"each hole's surface is taken from {cv.source}: a panel off its CAD by more than the form "
                 f"tolerance stated ({cv.form_tolerance_mm:g} mm) is not in U95; the redundant reading names the "
                 f"holes where it sees the shape off the CAD (the 'panel off its CAD' check)"]
    else:
        panel = ["the micro-plane's normal on a curved panel differs from the normal at the drill point to second "
                 "order in the spots' spread over the radius (docs/measure.md gives its size); no panel was given, "
                 f"the radius >= {report.min_radius_mm:g} mm is " + ("assumed" if cv.assumed else "stated")]
    return panel + ["the drift watch cannot tell which of 4 sensors moved: it gives the shift each one alone would "
                    "need"]


def measure_text(report) -> str:
    """The text report of ``metro measure`` (on stderr when the table goes to stdout)."""
    s = report.result.summary
    c = report.counts
    total = max(report.result.rows, 1)
    v = report.verdict
    fig = s.figures(s.total())
    lines = [f"metro measure: {report.result.rows:,} holes of {report.sources.log} "
             f"({report.result.partitions} partition(s)), layout {report.sources.layout}, {report.engine}",
             f"{c.fails:,} holes fail, {c.undecided:,} undecided against a tolerance of "
             f"{report.tolerance_deg:g} deg (ISO 14253-1 decision rule with U95)",
             f"judged: {_judged(report)}",
             *([f"resumed: {report.result.partitions - report.result.written} of {report.result.partitions} "
                f"partition(s) kept as an earlier run wrote them, {report.result.written} written (every hole "
                f"measured again: the summary, the verdict and the drift watch cover the whole log)"]
               if report.sources.out and report.result.written < report.result.partitions else []),
             "",
             f"{'status':<14}{'holes':>14}{'share':>9}"]
    for k in ("conforms", "fails", "undecided", "not_measured"):
        lines.append(f"{k:<14}{getattr(c, k):>14,}{100 * getattr(c, k) / total:>8.2f}%")
    lines += ["",
              f"angle before the adjustment [deg]: median {_q(fig, 'before', 'p50')}, p95 {_q(fig, 'before', 'p95')}, "
              f"p99.9 {_q(fig, 'before', 'p99_9')}",
              f"angle after the adjustment [deg]:  median {_q(fig, 'after', 'p50')}, p95 {_q(fig, 'after', 'p95')}, "
              f"p99.9 {_q(fig, 'after', 'p99_9')}",
              (f"judged angle: mean {fig.mean_deg:.4g} deg, s {fig.sd_deg:.3g} deg; {_ppk(fig)} against "
               f"{report.tolerance_deg:g} deg (ISO 22514-2 percentile method, one-sided upper: (tol - X50) / "
               f"(X99.865 - X50); the angle is bounded below by 0, not normal)" if np.isfinite(fig.mean_deg) else
               "judged angle: none (no hole was judged)"),
              "uncertainty: reading noise" + (" + the calibration's covariance" if report.has_covariance else
                                              " (the layout has no calibration covariance)") + _panel_terms(report)
              + (f" + the head's terms ({', '.join(report.effects)}), removed from every reading" if report.effects
                 else "") + ", 95 %"]
    ch = report.chart
    lines += ["", f"drift watch: two-sided CUSUM on the redundant reading's misfit per cell (k {ch.k}, "
                  f"h {ch.h}, in-control ARL {ch.arl0_holes:,.0f} holes; a shift of 1 scale is "
                  f"flagged after {ch.arl_at_detectable_holes} holes on average; "
                  f"{ch.baseline_holes} holes of baseline per " + ("panel" if ch.by_panel else "cell") + ")"]
    if not report.result.watch.charts:
        lines.append("  no cell charted (the drift watch needs holes read by all 4 sensors of a 4-sensor head)")
    alarms = report.result.alarms
    if not alarms and report.result.watch.charts:
        lines.append(f"  no alarm on {len(report.result.watch.charts)} cell(s)")
    for a in alarms:
        lines.append("  " + _alarm_words(a))
    if report.result.written < report.result.partitions:
        lines.append(f"\n{report.result.partitions - report.result.written} partition(s) were already written by an "
                     f"earlier run and left as they are")
    from metrology.report.verdicts import verdict_text

    lines += ["", verdict_text(v)]
    for w in report.warnings:
        lines.append(f"warning: {w}")
    return "\n".join(lines)


def _hist_figure(report):
    from metrology.measure.summary import EDGES_DEG
    from metrology.report.style import pyplot

    plt = pyplot()
    tot = report.result.summary.total()
    fig, ax = plt.subplots(figsize=(7.5, 3.2))
    centres = np.sqrt(EDGES_DEG[1:] * EDGES_DEG[:-1])
    for hist, label in ((tot.hist_before, "before the adjustment"), (tot.hist_after, "after the adjustment")):
        h = hist[1:]
        if h.sum():
            ax.step(centres, h / h.sum(), where="mid", label=label)
    ax.axvline(report.tolerance_deg, color="k", ls="--", lw=1, label=f"tolerance {report.tolerance_deg:g} deg")
    ax.set_xscale("log")
    seen = np.flatnonzero(tot.hist_before[1:] + tot.hist_after[1:])  # the axis spans the angles measured
    if seen.size:
        ax.set_xlim(EDGES_DEG[1:][seen[0]] / 1.5, max(EDGES_DEG[1:][min(seen[-1] + 1, len(EDGES_DEG) - 2)] * 1.5,
                                                         2 * report.tolerance_deg))
    ax.set_xlabel("angle between drill axis and measured normal [deg]")
    ax.set_ylabel("share of holes per bin [1]")
    ax.legend()
    fig.tight_layout()
    return fig


#: colour of the drift chart's CUSUM line (the browser check looks for it)
CUSUM_COLOUR = "#1f77b4"


def _chart_figure(chart, alarms):
    """The CUSUM of one cell against hours since its first charted hole: the chart's series
    (every peak and crossing kept, :class:`metrology.measure.chart.CusumChart`), broken where
    the chart took a new baseline; the alarms as red lines. The figure states where its line must
    show (near h at each alarm) and must not (over each new baseline's holes), in image pixels,
    for the browser check (:func:`metrology.report.html.expect_ink`)."""
    from metrology.report.html import expect_ink
    from metrology.report.style import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 2.6))
    if chart.series:
        t, s = np.array(chart.series, float).T
        hours = (t - t[0]) / 3600.0
        for a in alarms:
            ax.axvline((a.time_s - t[0]) / 3600.0, color="C3", lw=1)
        ax.axhline(chart.h, color="k", ls="--", lw=1, label=f"h = {chart.h:g}")
        ax.plot(hours, s, lw=1.0, color=CUSUM_COLOUR, label="CUSUM", zorder=3)
        ax.set_xlabel(f"hours since the first charted hole, {utc(t[0])} (after the cell's "
                      f"{chart.baseline_holes} baseline holes)")
        ax.legend(loc="upper left")
        ax.set_ylim(bottom=min(-0.5, np.nanmin(s)), top=max(np.nanmax(s), chart.h) * 1.08)
        ax.set_xlim(hours[0], hours[-1])
        gaps = np.flatnonzero(np.isnan(s))
        for a in alarms:
            x = (a.time_s - t[0]) / 3600.0
            i = np.flatnonzero((hours == x) & ~np.isnan(s))
            top = float(s[i].max()) if i.size else chart.h
            expect_ink(ax, (x, x), (chart.h - 1.0, top), CUSUM_COLOUR, True, pad_px=(3, 2))
        for g in gaps:
            nxt = np.flatnonzero(~np.isnan(s[g + 1:]))
            if nxt.size:
                expect_ink(ax, (hours[g], hours[g + 1 + nxt[0]]), ax.get_ylim(), CUSUM_COLOUR, False,
                           pad_px=(-4, 0))
    ax.set_ylabel("CUSUM [scales]")
    ax.set_title(f"cell {chart.cell}")
    fig.tight_layout()
    return fig


def measure_section(report):
    """The HTML section of ``metro measure``: verdict, histogram, one control chart per cell, tables."""
    from metrology.report.html import Section, Table, figure_from_matplotlib, verdict_box

    s = report.result.summary
    c = report.counts
    v = report.verdict
    head = (f"{c.conforms:,} of {report.result.rows:,} holes conform, {c.fails:,} fail, {c.undecided:,} are "
            f"undecided and {c.not_measured:,} were not measured, against {report.tolerance_deg:g} deg (ISO 14253-1, U95)")
    alarms = report.result.alarms
    kept = sum(1 for a in alarms if a.persisted)
    cause = ("no drift alarm" if not alarms else
             f"{kept} drift alarm(s) whose change persisted: recalibrate" if kept == len(alarms) else
             f"{kept} drift alarm(s) whose change persisted (recalibrate), {len(alarms) - kept} whose run did not "
             f"(check the head)")
    figs = [figure_from_matplotlib(_hist_figure(report), "Angle between the drill axis and the measured normal, before "
                                   "and after the attitude adjustment (log axis); dashed: the tolerance.")]
    for cell, chart in sorted(report.result.watch.charts.items())[:12]:
        figs.append(figure_from_matplotlib(_chart_figure(chart, [a for a in alarms if a.cell == cell]),
                                           f"Drift watch of cell {cell}: the CUSUM of the redundant reading's misfit; "
                                           f"dashed: the decision interval h; red: alarms."))
    counts, angles = [], []
    for cell, grp in sorted(s.series.items())[:_MAX_GROUP_ROWS]:
        f = s.figures(grp)
        k = s.counts(grp)
        counts.append((cell or "-", f"{k.total:,}", f"{k.conforms:,}", f"{k.fails:,}", f"{k.undecided:,}",
                       f"{k.not_measured:,}"))
        angles.append((cell or "-", _q(f, "before", "p50"), _q(f, "after", "p50"), _q(f, "after", "p99"),
                       _ppk(f, short=True)))
    note = (f"{len(s.series) - _MAX_GROUP_ROWS} more in --json" if len(s.series) > _MAX_GROUP_ROWS else
            f"per panel and day (UTC): {len(s.groups)} groups in --json")
    tables = [Table("Holes by status, per cell", ("cell", "holes", "conform", "fail", "undecided", "not measured"),
                    tuple(counts), note),
              Table("The angle per cell [deg]: quantiles before and after the adjustment; the judged angle's Ppk "
                    "(ISO 22514-2 percentile method, one-sided upper) with its 95 % bootstrap interval",
                    ("cell", "p50 before", "p50 after", "p99 after", "Ppk [95 % CI]"), tuple(angles))]
    worst = tuple((w.hole_id, f"{w.cell or '-'} {w.panel or '-'}", _when(w.time_s), f"{w.angle_deg:.4f}",
                   f"{w.U95_deg:.4f}", w.status) for w in s.worst)
    tables.append(Table("The worst holes: the largest judged angle", ("hole", "cell, panel", "time [UTC]", "angle [deg]",
                                                                       "U95 [deg]", "status"), worst))
    if alarms:
        # two narrow tables, not one of 8 columns (it ran past a 1280 px page and a phone's; issue 51)
        tables.append(Table("Drift alarms (where each run began: the text below)",
                            ("cell", "alarm at hole", "time [UTC]", "run [µm]", "level moved [µm]", "persisted"),
                            tuple((a.cell, a.hole_id, _when(a.time_s), f"{a.run_um:+.1f}", f"{a.size_um:+.1f}",
                                   "yes" if a.persisted else "no") for a in alarms)))
        names = list(dict.fromkeys(k for a in alarms for k in a.sensor_shift_um))
        tables.append(Table("Drift alarms: the zero shift of each sensor alone that explains the change [µm] "
                            "(one redundant reading cannot tell which)", ("alarm at hole", *names),
                            tuple((a.hole_id, *(f"{a.sensor_shift_um[k]:+.1f}" if k in a.sensor_shift_um else "-"
                                                for k in names)) for a in alarms)))
    if report.panel_map is not None:
        from metrology.report.panel_map import panel_map_figure

        figs.insert(0, figure_from_matplotlib(panel_map_figure(report.panel_map, report.tolerance_deg),
                                              "The panel's holes coloured by their judged angle (deg, the scale beneath), over the panel (grey); "
                                              "ringed red: holes that fail; grey crosses: holes not measured or not "
                                              "in the log."))
    limits = _limits(report)
    nxt = ["Recalibrate the head (metro plan, metro calibrate) before drilling on."] if alarms else []
    if c.undecided:
        nxt.append("Undecided holes: the measurement's U95 straddles the tolerance; inspect them or tighten U95 "
                   "(a better calibration lowers its share).")
    return Section("Hole measurement (metro measure)",
                   verdict_box(v, head, label=cause),
                   figures=tuple(figs), tables=tuple(tables), text=(measure_text(report),), limits=tuple(limits),
                   next_steps=tuple(nxt))

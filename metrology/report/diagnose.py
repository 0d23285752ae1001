"""Words and figures of a diagnosis: the text report and the residual plots."""

from __future__ import annotations

import numpy as np

from metrology.core.effects import REGISTRY
from metrology.diagnosis.decide import Diagnosis

__all__ = ["report_text", "plot_report", "p_text", "simulate_text", "diagnosis_figures", "discrepancy_lines",
           "structured_cells", "structure_level", "structure_rows", "GRID_MAX_VARIABLES", "UNEXPLAINED_NEXT"]

#: what to do when the residuals are not noise and no catalogued effect explains them
UNEXPLAINED_NEXT = (
    "check the export: a sensor's column swapped or mislabelled, a pose recorded twice, the units and quaternion "
    "order (--position-units, --quaternion-order)",
    "give the datum as its tracker cloud (--plane datum.ply): its form is then checked against the readings",
    "add poses that vary one thing at a time (stand-off, tilt, time, temperature), interleaved, so that a cause "
    "can be told apart from the others",
)


def p_text(p: float) -> str:
    """``= 0.0123`` or ``< 1e-300`` (a p-value that underflowed)."""
    return "< 1e-300" if p < 1e-300 else f"= {p:.3g}"


def detectable_words(D: dict) -> str:
    """``detectable`` of :meth:`Diagnosis.to_dict` in words: each family's smallest size over its
    sensors (and the largest, where they differ), in µm; the sensors where no size is (an
    effect of some shape of the family no member sees, ``inf``; ``null`` in JSON) are named."""
    import math

    out = []
    for fam, v in (D.get("detectable") or {}).items():
        vals = [1e3 * x for x in v["sensors"].values() if x is not None and math.isfinite(x)]
        never = [k for k, x in v["sensors"].items() if x is None or not math.isfinite(x)]
        if not vals and not never:
            continue
        words = []
        if vals:
            lo, hi = min(vals), max(vals)
            words.append((f"{lo:.3g}" if hi < 1.05 * lo else f"{lo:.3g}-{hi:.3g}") + " µm")
        if never:
            words.append("not detectable on " + ", ".join(never))
        out.append(f"{fam} {', '.join(words)} ({v['meaning']})")
    return "; ".join(out)


def _label_width(labels) -> int:
    """The width of a text table's label column: its longest label and two spaces, so that no
    row's numbers shift right of the header's."""
    return max((len(x) for x in labels), default=0) + 2


def discrepancy_lines(disc: dict) -> list:
    """The text table of ``discrepancy`` (:meth:`Diagnosis.to_dict`): residual RMS per sensor
    (µm) and held-out normal deviation (deg), stated noise, simulation and measurement, each
    number under its sensor's header."""
    rows = [("stated noise", disc["stated_noise_mm"], None),
            ("simulation, base model", disc["simulated_base_residual_rms_mm"],
             disc["simulated_base_heldout_normal_deg"]),
            ("measured", disc["measured_residual_rms_mm"], disc["measured_heldout_normal_deg"])]
    if "simulated_extended_residual_rms_mm" in disc:
        rows.append((f"simulation, + {disc['extended_model']}", disc["simulated_extended_residual_rms_mm"],
                     disc["simulated_extended_heldout_normal_deg"]))
    w = _label_width([r[0] for r in rows])
    lines = ["discrepancy (residual RMS µm per sensor; held-out normal deviation deg)",
             f"  {'':{w}s}" + "".join(f"{n:>9s}" for n in disc["sensors"]) + f"{'normal':>11s}"]
    for label, rms, nd in rows:
        lines.append(f"  {label:{w}s}" + "".join(f"{1e3 * v:9.2f}" for v in rms) + ("" if nd is None else f"{nd:11.5f}"))
    return lines


def reason_words(r: dict) -> str:
    """One entry of the verdict's trail (a ``reasons`` entry of the ``--json`` output) in words:
    the rule (its number and name in :mod:`metrology.diagnosis.rules`), what it decided on which
    candidates, the statistic against its level, the held-out gain weighed, what it gave."""
    head = f"rule {r['rule']:>2} {r['name']}" + (f", step {r['step']}" if r["step"] else "")
    what = r["decided"] + (f": {', '.join(r['concerns'])}" if r["concerns"] else "")
    figures = []
    level = "" if r["threshold"] is None else f"level {r['threshold']:.3g}"
    if r["value"] is not None:
        figures.append(f"{r['statistic']} {r['value']:.3g}" + (f" against {level}" if level else ""))
    elif level:
        figures.append(level)
    if r["gain"] is not None:
        figures.append(f"held-out chi-square gain {r['gain']:.3g}")
    if r["outcome"]:
        figures.append(f"gives {r['outcome']}")
    return f"{head}: {what}" + (f" ({'; '.join(figures)})" if figures else "")


def why_lines(D: dict) -> list:
    """The "why" of a diagnosis: the rules that made its verdict, in the order they fired."""
    return ["why (the rules that made the verdict, in the order they fired)"] + [
        f"  {reason_words(r)}" for r in D.get("reasons", ())]


def explain_text(d: Diagnosis) -> str:
    """What ``metro diagnose --explain`` prints: the verdict, its summary and its trail."""
    D = d.to_dict()
    return "\n".join(_verdict_lines(D) + [""] + why_lines(D))


def _verdict_lines(D: dict) -> list:
    lines = [f"cause: {D['cause']}" + (f" ({', '.join(D['sensors'])})" if D["sensors"] else "")
             + f"   confidence: {D['confidence']}", f"  {D['summary']}"]
    if D["cause"] == "unexplained":
        lines += ["  next: " + UNEXPLAINED_NEXT[0]] + ["        " + x for x in UNEXPLAINED_NEXT[1:]]
    return lines


def report_text(d: Diagnosis) -> str:
    """The text report of ``metro diagnose`` (read from :meth:`Diagnosis.to_dict`)."""
    D = d.to_dict()
    lines = _verdict_lines(D) + [""] + why_lines(D)
    lines.append("")
    lines += discrepancy_lines(D["discrepancy"])
    lines.append("")
    tb = D["tests"]["base"]
    lines.append(f"noise-model tests on the base residuals (Bonferroni p = {tb['p_bonferroni']:.3g}, "
                 f"{tb['n_tests']} tests): " + ("consistent" if tb["consistent"] else "INCONSISTENT"))
    for n, t in tb["sensors"].items():
        lines.append(f"  {n}: sigma {1e3 * t['sigma_est_mm']:.2f} µm  p_chi2 {t['p_chi2']:.3g}  "
                     f"p_white {t['p_whiteness']:.3g}  p_normal {t['p_normality']:.3g}")
    lines.append("")
    lines.append("candidates (held-out k-fold by pose), best first")
    shown = D["candidates"][:10]
    w = _label_width(["candidate"] + [c["label"] for c in shown])
    lines.append(f"  {'candidate':{w}s}{'p in-sample':>12s}{'p held-out':>12s}{'chi2 gain':>11s}{'RMS ratio':>11s}  sig")
    for c in shown:
        lines.append(f"  {c['label']:{w}s}{c['p_insample']:12.3g}{c['p_heldout']:12.3g}"
                     f"{c['heldout_chi2_reduction']:11.1f}{c['heldout_rms_ratio']:11.3f}  {'*' if c['significant'] else ''}")
    if len(D["candidates"]) > 10:
        lines.append(f"  ... {len(D['candidates']) - 10} more in --json")
    if D.get("detectable"):
        lines.append("detectable at 95 % power on these poses (metrology.diagnosis.detectable):")
        lines += [f"  {x}" for x in detectable_words(D).split("; ")]
    if D["causes"]:
        lines.append("")
        lines.append("residuals after each step of the selection (in-sample RMS µm per sensor; held-out RMS µm)")
        w = _label_width([st["model"] for st in D["steps"]])
        for st in D["steps"]:
            lines.append(f"  {st['model']:{w}s}" + "".join(f"{1e3 * v:9.2f}" for v in st["residual_rms_mm"])
                         + f"{1e3 * st['heldout_rms_mm']:11.3f}" + ("  (not named)" if st.get("named") is False else ""))
        for c in D["causes"]:
            where = f" on {', '.join(c['sensors'])}" if c["sensors"] else ""
            lines.append("")
            test = (f"{c['test']}, p = {c['p_insample']:.3g}" if c.get("test") else
                    f"held-out chi-square gain {c['heldout_gain_chi2']:.1f} given the others, p = {c['p_heldout_given_others']:.3g}")
            lines.append(f"cause {c['cause']}{where}: {c['label']} ({test})")
            if c.get("size"):
                sz = c["size"]
                se = "" if sz["stderr"] is None else f" +- {1e3 * sz['stderr']:.2f}"
                lines.append(f"  size {1e3 * sz['value']:.2f}{se} µm ({sz['meaning']})")
            if c.get("at"):  # an effect located in the run (a knocked sensor)
                at = c["at"]
                lines.append(f"  between the export's poses {at['last_pose_before'] + 1} and {at['first_pose_after'] + 1} "
                             f"(rows, from 1; t = {at['time_h']:.4g} h since the first pose, or the pose index without "
                             f"time; {at['positions_searched']} positions searched)")
            for k, v in c["params"].items():
                se = "" if v["stderr"] is None else f" +- {v['stderr']:.3g}"
                lines.append(f"  {k} = {v['value']:.4g}{se} {v['unit']}")
        h = D["heldout"]
        lines.append(f"held-out ({h['folds']}-fold), base -> {h['model']}: RMS {1e3 * h['base_rms_mm']:.3f} -> "
                     f"{1e3 * h['extended_rms_mm']:.3f} µm (ratio {h['rms_ratio']:.3f}; its sensors "
                     f"{h['rms_ratio_concerned']:.3f}), normal {h['base_normal_deg']:.5f} -> {h['extended_normal_deg']:.5f} "
                     f"deg (ratio {h['normal_ratio']:.3f})")
    for c in D["confounding"]:
        lines.append(f"confounding: {c['message']}")
    df = D["datum_form"]
    if df is not None:
        q = "  ".join(f"{k[:-3]} {v['value'] * 1e3:.2f} +- {v['stderr'] * 1e3:.2f}" for k, v in df["params"].items()
                      if k in REGISTRY["plane_form"].key_params)
        vis = ", ".join(f"{1e3 * v:.2f}" for v in df["visible_rms_mm"])
        ag = df["against_readings"]
        lines += ["", f"datum cloud ({df['points_used']} of {df['points']} points, {df['window']}): form {q} µm at "
                      f"{df['radius_mm']:g} mm (quadratic p {p_text(df['p_quadratic'])})",
                  f"  at this run's spots it would leave {vis} µm RMS in the base residuals (per sensor)",
                  f"  the readings' plane_form ({' + '.join(ag['fitted_with'])}) {'agrees' if ag['agree'] else 'DISAGREES'} "
                  f"with it (p {p_text(ag['p'])})"]
    return "\n".join(lines)



def plot_report(diag: Diagnosis, out_dir) -> list:
    """Residual plots that made the case, before and after, each written atomically as PNG
    into ``out_dir`` (created if missing); returns the files written."""
    from pathlib import Path

    from metrology.report.plots import save_figure

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for name, fig, _ in diagnosis_figures(diag):
        save_figure(fig, out / name, dpi=90)
        files.append(str(out / name))
    return files


#: the words of each covariate the residuals are plotted against (axis labels with units)
AXIS_WORDS = {"d_mm": "reading [mm]", "incidence_deg": "incidence [deg]", "time_h": "time [h]",
              "temp_c": "temperature [°C]", "spot_s_mm": "spot s [mm]", "spot_t_mm": "spot t [mm]",
              "pose_index": "pose [index]"}

#: the overview grid draws a (variable, sensor) cell of the base residuals' structure table
#: (:func:`metrology.diagnosis.stats.structure`, a quadratic trend's F-test) whose p is below
#: the noise-model battery's family-wise level (``THRESHOLDS["alpha_battery"]``) split over
#: the table's cells (Bonferroni): a panel is drawn where a trend would fail the noise model;
#: every cell's R² and p is in the structure table of the report
#: the grid's most columns (variables, the most structured first): three panels across the
#: page's column (:data:`metrology.report.html.COLUMN_IN`, 10 in), 3.3 in each, leave their
#: 9 pt tick labels apart; a variable beyond them is in the table
GRID_MAX_VARIABLES = 3


def structured_cells(structure: dict) -> list:
    """The cells of a structure table (``variable -> sensor ->``
    :class:`~metrology.diagnosis.stats.Trend`) that carry structure (see
    :data:`GRID_MAX_VARIABLES`'s rule): (variable, sensor, r2, p), smallest p first."""
    cells = [(k, s, v.r2, v.p) for k, row in structure.items() for s, v in row.items()]
    level = structure_level(structure)
    return sorted((c for c in cells if c[3] < level), key=lambda c: c[3])


def _grid(structure: dict, names, variables) -> tuple:
    """The overview grid's variables (keys, most structured first, at most
    :data:`GRID_MAX_VARIABLES`) and sensors (indices, in the layout's order): those of the cells
    that carry structure."""
    cells = [c for c in structured_cells(structure) if c[0] in variables]
    keys = list(dict.fromkeys(c[0] for c in cells))[:GRID_MAX_VARIABLES]
    rows = [i for i, nm in enumerate(names) if any(c[1] == nm and c[0] in keys for c in cells)]
    return keys, rows


def structure_level(structure: dict) -> float:
    """The p below which a cell of ``structure`` carries structure (:data:`GRID_MAX_VARIABLES`'s rule)."""
    from metrology.diagnosis.thresholds import THRESHOLDS

    return THRESHOLDS["alpha_battery"] / max(sum(len(row) for row in structure.values()), 1)


def structure_rows(diag: Diagnosis) -> tuple:
    """The structure table of the base residuals as report rows: per variable (in words), per
    sensor the R² of the quadratic trend, a cell that carries structure (:func:`structured_cells`)
    marked ``*`` (the p of each is in ``--json``'s ``structure`` and on its panel)."""
    marked = {(c[0], c[1]) for c in structured_cells(diag.structure_base)}
    out = []
    for key, row in diag.structure_base.items():
        cells = []
        for nm in diag.discrepancy.sensors:
            v = row.get(nm)
            cells.append("—" if v is None else f"{v.r2:.2f}" + ("*" if (key, nm) in marked else ""))
        out.append((AXIS_WORDS.get(key, key), *cells))
    return tuple(out)


def diagnosis_figures(diag: Diagnosis) -> list:
    """The residual figures that made the case: (file name, matplotlib figure, caption) for the
    base residuals against the variables and on the sensors that carry structure
    (:func:`structured_cells`; none when no cell does), and, when a cause is named, the
    held-out residuals before and after it (the figures the ``heldout`` RMS of the text are of)."""
    from metrology.report.html import COLUMN_IN
    from metrology.report.style import pyplot

    plt = pyplot()
    P = diag.plot_data
    base, cov, names, d0 = P.base, P.cov, P.names, P.d0
    files = []
    p, n = base.residual.shape
    variables = {
        "d_mm": d0, "incidence_deg": np.rad2deg(np.arccos(np.clip(cov.cos_inc, -1, 1))),
        "time_h": np.broadcast_to(cov.time_h[:, None], (p, n)), "temp_c": np.broadcast_to(cov.temp_c[:, None], (p, n)),
        "spot_s_mm": cov.spot_st[..., 0], "spot_t_mm": cov.spot_st[..., 1],
        "pose_index": np.broadcast_to(np.arange(p, dtype=float)[:, None], (p, n)),
    }
    variables = {k: v for k, v in variables.items() if np.all(np.isfinite(v))}
    keys, rows = _grid(P.structure, names, variables)
    if keys:
        width = min(COLUMN_IN, 3.3 * len(keys) + 0.6)
        fig, axes = plt.subplots(len(rows), len(keys), figsize=(width, 0.5 + 2.3 * len(rows)), squeeze=False,
                                 sharey="row", layout="constrained")
        for r, i in enumerate(rows):
            for j, key in enumerate(keys):
                ax = axes[r, j]
                ax.plot(variables[key][:, i], base.residual[:, i] * 1e3, ".", ms=3)
                ax.axhline(0, color="k", lw=0.5)
                cell = P.structure.get(key, {}).get(names[i])
                if cell is not None:
                    ax.set_title(f"{names[i]}: R² {cell.r2:.2f}, p {p_text(cell.p)}", fontsize=9)
                if r == len(rows) - 1:
                    ax.set_xlabel(AXIS_WORDS.get(key, key))
                if j == 0:
                    ax.set_ylabel(f"{names[i]} residual [µm]")
        fig.suptitle("base model: residuals where they carry structure")
        files.append(("residuals_base.png", fig, "Residuals of the base model (calibrated geometry only) against the "
                      "variables and on the sensors where a trend is significant (quadratic fit's F-test, "
                      "Bonferroni over the structure table's cells); every cell's R² and p is in the structure table. "
                      "A trend is what the base model misses."))
    best = P.best
    if best is not None and best.fit.components and P.heldout_after is not None:
        # (a random pose error alone fits no term to draw)
        comp = best.fit.components[0]
        key = comp.plot_key  # from the effect registry
        cols = list(comp.sensors) if comp.sensors else list(range(n))
        model = comp.label if diag.heldout.model is None else diag.heldout.model
        fig, axes = plt.subplots(len(cols), 2, figsize=(COLUMN_IN, 0.6 + 2.5 * len(cols)), squeeze=False,
                                 sharey="row", layout="constrained")
        X = variables.get(key, variables["pose_index"])
        term = comp.evaluate(comp.values, d0, cov)
        for r, i in enumerate(cols):
            a0, a1 = axes[r]
            before, after = P.heldout_base[:, i], P.heldout_after[:, i]
            a0.plot(X[:, i], before * 1e3, ".", ms=3, label="held-out residual")
            order = np.argsort(X[:, i])
            if comp.plot_term:
                a0.plot(X[order, i], (term[order, i] - np.nanmean(term[:, i]) + np.nanmean(before)) * 1e3,
                        "-", color="C3", label=f"fitted {comp.name}")
            a1.plot(X[:, i], after * 1e3, ".", ms=3, color="C2")
            for a, res, word in ((a0, before, "before (base)"), (a1, after, "after")):
                a.axhspan(-1e3 * P.sigma[i], 1e3 * P.sigma[i], color="0.85", lw=0)
                a.axhline(0, color="k", lw=0.5)
                if r == len(cols) - 1:
                    a.set_xlabel(AXIS_WORDS.get(key, key))
                a.set_title(f"{word}: RMS {1e3 * np.sqrt(np.nanmean(res ** 2)):.2f} µm", fontsize=9)
            a0.set_ylabel(f"{names[i]} residual [µm]")
            if r == 0:
                a0.legend(fontsize=9)
        fig.suptitle(f"held-out residuals (k-fold by pose), base and base + {model}; grey: stated noise ± 1 σ")
        files.append(("residuals_named.png", fig, f"Held-out residuals (each a prediction of a pose left out of the "
                      f"fit) of the base model and of the base model + {model}, on the sensors of {comp.label}; grey: "
                      "the stated noise, ± 1 σ. These are the residuals of the held-out RMS in the text, not the "
                      "in-sample ones (which are smaller by the parameters fitted to them)."))
    figure = _empirical_figure(diag, plt)
    if figure is not None:
        files.append(figure)
    return files


def _empirical_figure(diag: Diagnosis, plt):
    """The open search's terms (``diag.empirical``), one partial-residual panel each: the residual
    with the term added back against the term's variable, and the fitted term; None without terms."""
    from metrology.report.html import COLUMN_IN

    terms = [t for t in (diag.empirical.terms if diag.empirical is not None else ()) if t.plot is not None]
    if not terms:
        return None
    fig, axes = plt.subplots(len(terms), 1, figsize=(COLUMN_IN, 0.6 + 2.5 * len(terms)), squeeze=False,
                             layout="constrained")
    for ax, t in zip(axes[:, 0], terms):
        x, y, f = (np.asarray(t.plot[k], float) for k in ("x", "partial", "fit"))
        order = np.argsort(x)
        ax.plot(x, 1e3 * y, ".", ms=3, label="partial residual")
        ax.plot(x[order], 1e3 * f[order], "-", color="C3", label="fitted term")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel(t.plot["xlabel"])
        ax.set_ylabel(f"{t.sensor} [µm]")
        ax.set_title(t.equation, fontsize=9)
    axes[0, 0].legend(fontsize=9)
    fig.suptitle("outside the catalogue: the open search's terms (partial residuals)")
    return ("residuals_empirical.png", fig, "Each term the open search took: the sensor's residual under the model "
            "the verdict judged, less the other terms, with this term added back (its partial residual), against "
            "the term's variable, and the fitted term.")


def simulate_text(out, poses, effect, sensor, size, cloud, n_points) -> str:
    """The one line ``metro simulate`` prints: what was written and what it hides."""
    return (f"wrote {out}: {poses} poses" + (f", hiding {effect} of size {size:g}"
                                              + (f" on {sensor}" if sensor else "") if effect else "")
            + (f"; {cloud}: {n_points} datum points" if n_points is not None else ""))

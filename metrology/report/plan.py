"""Words and figures of ``metro plan`` and of ``metro calibrate --follow``."""

from __future__ import annotations

import numpy as np

from metrology.plan.plan import PosePlan

__all__ = ["plan_text", "plot_plan_curve", "follow_line", "CURVE_KS"]

#: the pose counts shown in the text's curve (those up to N, and N)
CURVE_KS = (5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50, 60, 80, 100, 150, 200)
#: how the report prints the standard errors of each extra design column (``Design.columns``)
_EXTRA_WORDS = {"incidence": "incidence c {:.4f} mm", "scale": "gain k {:.2e}", "nonlinearity": "curve c2, c3 {:.4f} {:.4f} mm"}


def _extra_words(columns, se) -> str:
    """``; incidence c ... mm; gain k ...``: the extra columns' standard errors ``se``."""
    out, j = "", 0
    for c in columns:
        k = _EXTRA_WORDS[c].count("{")
        out += "; " + _EXTRA_WORDS[c].format(*se[j:j + k])
        j += k
    return out


def _num(v, fmt):
    return "-" if v is None or not np.isfinite(v) else format(v, fmt)


def plan_text(plan: PosePlan, out=None) -> str:
    """The plan in words: the criterion, the limits, planned against random, and the curve."""
    p, r = plan.planned, plan.random
    lim = plan.limits
    lines = [f"criterion: {plan.to_dict()['criterion']}",
             f"candidates: {plan.n_feasible} of {plan.n_candidates} keep every limit (tilt <= "
             f"{np.rad2deg(lim.tilt_max_rad):g} deg less {np.rad2deg(lim.tilt_margin_rad):g}, stand-off "
             f"{lim.standoff_mm[0]:g}-{lim.standoff_mm[1]:g} mm, readings {lim.reading_margin_mm:g} mm inside the range, "
             f"spots {lim.spot_margin_mm:g} mm inside the datum's extent)",
             f"noise {', '.join(f'{s:g}' for s in plan.sigma_mm)} mm; normal predicted at the working stand-off "
             f"{plan.working_standoff_mm:g} mm (datum perpendicular to the tool axis)", ""]
    lines.append(f"{'':8} {'poses':>5} {'max zero sigma mm':>17} {'max tilt sigma deg':>18} {'normal sigma deg':>16}")
    for d in (p, r):
        lines.append(f"{d.label:8} {len(d.poses):5d} {d.stderr[:, :3].max():17.4f} "
                     f"{np.rad2deg(d.stderr[:, 3:5].max()):18.4f} {np.rad2deg(d.normal_sigma_rad):16.5f}")
    lines.append(f"D-efficiency of the random poses against the plan: {plan.d_efficiency_random:.2f} "
                 "(information per parameter, geometric mean)")
    lines += ["", "planned, per sensor (1 sigma): zero x, y, z mm; tilt e1, e2 deg"]
    for i, name in enumerate(plan.layout.names):
        se = p.stderr[i]
        lines.append(f"  {name}: {se[0]:.4f} {se[1]:.4f} {se[2]:.4f} mm; {np.rad2deg(se[3]):.4f} "
                     f"{np.rad2deg(se[4]):.4f} deg"
                     + _extra_words(p.columns, se[5:])
                     + f"; readings {p.reading_span_mm[i, 0]:.1f}-{p.reading_span_mm[i, 1]:.1f} mm")
    lines += ["", "stopping early: the first k planned poses (random in brackets)",
              f"  {'k':>4} {'max zero mm':>16} {'max tilt deg':>16} {'normal deg':>18}"]
    n = len(p.poses)
    for k in sorted({k for k in CURVE_KS if k <= n} | {n}):
        c, q = p.curve, r.curve
        j = k - 1
        lines.append(f"  {k:4d} {_num(c['zero_sigma_max_mm'][j], '7.4f'):>7} ({_num(q['zero_sigma_max_mm'][j], '.3f'):>6}) "
                     f"{_num(np.rad2deg(c['tilt_sigma_max_rad'][j]), '7.4f'):>7} ({_num(np.rad2deg(q['tilt_sigma_max_rad'][j]), '.3f'):>6}) "
                     f"{_num(np.rad2deg(c['normal_sigma_rad'][j]), '8.5f'):>8} ({_num(np.rad2deg(q['normal_sigma_rad'][j]), '.5f'):>8})")
    rb = p.robustness
    if rb:
        lines += ["", f"robot error {rb['robot_error_mm']:g} mm and {rb['robot_error_deg']:g} deg at every pose "
                  f"({rb['trials']} trials): {100 * rb['feasible_fraction']:.1f} % of the poses stay feasible without "
                  f"margins, D-efficiency {rb['d_efficiency_min']:.3f}-{rb['d_efficiency_max']:.3f}, normal sigma up to "
                  f"{rb['normal_sigma_deg_max']:.5f} deg"]
    if out is not None:
        lines += ["", f"poses written to {out} (fill the d_ columns, then: metro calibrate {out} ...)"]
    return "\n".join(lines)


def plot_plan_curve(plan: PosePlan, path) -> None:
    """Predicted 1-sigma against the number of poses taken, planned and random (PNG/PDF/SVG)."""
    from metrology.report.plots import pyplot, save_figure

    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    keys = (("zero_sigma_max_mm", "largest zero-point sigma [mm]", 1.0),
            ("tilt_sigma_max_rad", "largest beam-tilt sigma [deg]", np.rad2deg(1.0)),
            ("normal_sigma_rad", "normal sigma at working stand-off [deg]", np.rad2deg(1.0)))
    for ax, (key, label, f) in zip(axes, keys):
        for d, style in ((plan.planned, "-"), (plan.random, "--")):
            y = np.where(np.isfinite(d.curve[key]), d.curve[key] * f, np.nan)
            ax.plot(d.curve["k"], y, style, label=d.label)
        ax.set_yscale("log")
        ax.set_xlabel("poses taken, k")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    save_figure(fig, path)


def follow_line(step) -> str:
    """One line per pose of ``calibrate --follow``: each sensor's largest standard errors and the
    normal's, and whether the targets are met (``step`` a :class:`~metrology.calibration.follow.FollowStep`)."""
    parts = [f"{step.k:4d} {step.pose_id}:"]
    known = np.all(np.isfinite(step.stderr), axis=1)
    if not np.any(known):  # no sensor has enough readings yet (a planned file before the cell fills it)
        return " ".join(parts + ["waiting for readings"])
    for name, se, ok in zip(step.names, step.stderr, known):
        parts.append(f"{name} zero {se[:3].max():.4f} mm tilt {np.rad2deg(se[3:].max()):.4f} deg;" if ok else
                     f"{name} waiting for readings;")
    sn = np.rad2deg(step.normal_sigma_rad)
    parts.append(f"normal {sn:.5f} deg" if np.isfinite(sn) else "normal: waiting for readings")
    if step.met:
        parts.append("| targets met")
    return " ".join(parts)

"""Text, figure and report section of a validation (``metro validate``).

``validation.png`` is the deviation of the measured normal from the datum normal per pose,
one series per layout (the paper's Figure 12), on a log axis (a calibrated layout is often a
hundred times closer than the nominal one), with the drilling tolerance drawn; the series are
named by the files the user gave.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metrology.calibration.validation import ValidationReport
from metrology.core.tolerances import DRILLING_TOLERANCE_DEG
from metrology.report.verdicts import validation_checks, verdict_text

__all__ = ["validation_text", "plot_validation", "validation_figure", "validation_verdict", "layout_words",
           "left_out"]

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
_ROLE = {"layout_before": "before", "layout": "validated"}


def layout_words(report: ValidationReport, label: str) -> str:
    """A layout named as the user gave it: ``calibrated.toml (validated)``, ``nominal.toml (before)``."""
    src = report.sources.get(label)
    role = _ROLE.get(label, label)
    return f"{Path(src).name} ({role})" if src else role


def left_out(report: ValidationReport) -> tuple:
    """Pose ids with fewer than 3 readings (no normal: left out of the statistics)."""
    return tuple(p for p, n in zip(report.pose_id, report.n_readings) if n < 3)


def validation_verdict(report: ValidationReport, tolerance_deg: float = DRILLING_TOLERANCE_DEG) -> dict:
    """The validated layout (the last) against the tolerance.

    Returns dict: ``ok`` (max deviation <= tolerance), ``label``, ``max_deg``, ``mean_deg``,
    ``mean_stderr_deg`` (std / sqrt(n), the 1-sigma of the mean), ``std_deg``, ``n_poses``,
    ``tolerance_deg``, ``margin`` (tolerance / max), ``improvement`` (mean before / mean
    validated, when a layout before was given, else None).
    """
    k = len(report.labels) - 1
    s = report.stats_deg(k)
    n = s["n_poses"]
    out = {**s, "label": report.labels[k], "tolerance_deg": float(tolerance_deg),
           "ok": bool(s["max_deg"] <= tolerance_deg),
           "mean_stderr_deg": float(s["std_deg"] / np.sqrt(n)) if n > 1 else float("nan"),
           "margin": float(tolerance_deg / s["max_deg"]) if s["max_deg"] > 0 else float("inf"), "improvement": None}
    if k > 0:
        b = report.stats_deg(0)
        out["improvement"] = float(b["mean_deg"] / s["mean_deg"]) if s["mean_deg"] > 0 else float("inf")
    return out


def validation_text(report: ValidationReport, tolerance_deg: float = DRILLING_TOLERANCE_DEG) -> str:
    """What ``metro validate`` prints: max / mean / std per layout, the poses left out, and the
    verdict of the validated layout against the tolerance."""
    words = [layout_words(report, lab) for lab in report.labels]  # the user's words, as the HTML and figure
    w = max(14, *(len(x) for x in words))
    lines = [f"{'layout':<{w}} {'max [deg]':>10} {'mean [deg]':>10} {'std [deg]':>10} {'poses':>6}  file"]
    for k, lab in enumerate(report.labels):
        s = report.stats_deg(k)
        lines.append(f"{words[k]:<{w}} {s['max_deg']:10.4f} {s['mean_deg']:10.4f} {s['std_deg']:10.4f} {s['n_poses']:6d}  "
                     f"{report.sources.get(lab, '')}")
    partial = int(np.sum((report.n_readings < report.n_sensors) & (report.n_readings >= 3)))
    gone = left_out(report)
    if gone:
        lines.append(f"{len(gone)} pose(s) with fewer than 3 readings: no normal, left out ({', '.join(gone)})")
    if partial:
        lines.append(f"{partial} pose(s) with a missing reading: normal from the least-squares plane of the rest")
    v = validation_verdict(report, tolerance_deg)
    lines.append(f"{layout_words(report, v['label'])}: max {v['max_deg']:.4f} deg, mean {v['mean_deg']:.4f} ± "
                 f"{v['mean_stderr_deg']:.4f} deg (1 σ of the mean) over {v['n_poses']} poses")
    lines.append(verdict_text(validation_checks(v)))
    return "\n".join(lines)


def validation_figure(report: ValidationReport, tolerance_deg: float | None = DRILLING_TOLERANCE_DEG):
    """The deviation per pose (log axis), one series per layout, the tolerance as a line;
    returns the matplotlib figure."""
    from matplotlib.ticker import MaxNLocator

    from metrology.report.style import plain_log_ticks, pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.2))
    x = np.arange(1, len(report.pose_id) + 1)
    markers = ("o", "s", "^", "D", "v")
    for k, label in enumerate(report.labels):
        s = report.stats_deg(k)
        y = np.rad2deg(report.deviation[k])
        ax.plot(x, np.clip(y, 1e-6, None), marker=markers[k % len(markers)], ms=4, lw=0.8,
                color=_COLOURS[k % len(_COLOURS)],
                label=f"{layout_words(report, label)}: max {s['max_deg']:.4f}, mean {s['mean_deg']:.4f} deg")
    if tolerance_deg is not None:
        ax.axhline(tolerance_deg, color="tab:red", ls="--", lw=1.2, label=f"tolerance {tolerance_deg:g} deg")
    gone = np.flatnonzero(report.n_readings < 3)
    if len(gone):
        for j in gone:
            ax.axvline(j + 1, color="0.6", ls=":", lw=0.8)
        ax.plot([], [], color="0.6", ls=":", label="pose left out (< 3 readings)")
    ax.set_yscale("log")
    finite = np.rad2deg(report.deviation[np.isfinite(report.deviation)])
    top = max(float(finite.max()) if finite.size else 1.0, tolerance_deg or 0.0)
    ax.set_ylim(top=top * 2.0)
    ax.set_xlabel("validation pose [index]")
    ax.set_ylabel("deviation of the measured normal [deg]")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(loc="best")
    ax.set_title("measured normal against the datum normal, per pose (log axis)")
    plain_log_ticks(ax)
    fig.tight_layout()
    return fig


def plot_validation(report: ValidationReport, path, tolerance_deg: float | None = DRILLING_TOLERANCE_DEG) -> Path:
    """Write :func:`validation_figure` to ``path`` atomically (format from the suffix)."""
    from metrology.report.plots import save_figure

    save_figure(validation_figure(report, tolerance_deg), path)
    return Path(path)

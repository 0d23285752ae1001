"""Text and figures of a calibration and a validation (PNG, written atomically).

:func:`calibration_text` and :func:`validation_text` are what ``metro calibrate`` and
``metro validate`` print.

``convergence.png``
    The estimated errors of every parameter against the number of measurements, one row
    per sensor (the paper's Figures 7 and 11). For the EKFs, the filter's own history (the
    paper's raw errors dx, dy, dz mm and dm, dn, dq of the direction vector); for the batch
    methods, the estimate from the first k poses with its +-1 sigma band (zero mm, tilt deg).
``residuals.png``
    Reading residuals (measured - predicted, mm) of the calibrated layout against the
    reading, the incidence angle of the beam on the datum and the pose index.
``validation.png``
    Angular deviation of the measured normal from the datum normal per pose, one series per
    layout (the paper's Figure 12).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


from metrology.calibration.calibrate import CalibrationReport
from metrology.calibration.convergence import residual_table
from metrology.calibration.identifiability import CHART_NAMES, sigma_words
from metrology.report.fit_report import FitSummary, correlations_from_cov, fit_report
from metrology.report.plots import pyplot, save_figure
from metrology.report.verdicts import verdict_text
from metrology.report.validation import plot_validation, validation_text  # noqa: F401 (their home before)

__all__ = ["calibration_text", "validation_text",
           "plot_convergence", "plot_residuals", "plot_validation", "write_calibration_plots", "convergence_figure",
           "residuals_figure", "fit_summaries", "check_plot_target"]

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def _vec(v, digits):
    return "[" + ", ".join(f"{x:.{digits}f}" for x in v) + "]"


def calibration_text(report: CalibrationReport) -> str:
    """A human-readable calibration report (what ``metro calibrate`` prints)."""
    d = report.to_dict()
    lines = [f"method {d['method']}: {d['n_poses']} poses, datum normal {np.round(d['datum']['normal'], 6).tolist()} "
             f"offset {d['datum']['offset_mm']:.4f} mm (tracker frame)"]
    for s, fit in zip(d["sensors"], fit_summaries(report)):
        c = s["corrected"]
        conv = "" if s["n_converged"] is None else f", converged after {s['n_converged']} measurements"
        lines.append(f"{s['name']}: {s['n_readings']} readings, residual RMS {s['residual_rms_mm']:.4f} mm "
                     f"(stated noise {s['noise_mm']:.4g} mm){conv}; beam tilt total {s['error']['tilt_total_deg']:.4f} deg")
        lines.append("  corrected    zero " + _vec(c["zero_mm"], 4) + " mm, direction " + _vec(c["direction"], 6))
        lines += ["  " + x for x in fit_report(fit).splitlines()]
    lines.append(f"unidentified: {d['unidentified']}")
    for t in d.get("effects", []):  # the head's terms estimated with the sensors
        vals = ", ".join(f"{p} {v['value']:.6g} +- {v['U_k2']:.2g} (U, k = 2) {v['unit']}" for p, v in t["params"].items())
        lines.append(f"term {t['label']}: {vals}; " + ("identified by these poses" if t["identified"] else
                                                       f"not identified: {t['why_not']}"))
    for ident in report.identifiability:
        sv = " ".join(f"{v:.2g}" for v in ident.chart_singular)
        lines.append(f"{ident.name}: chart singular values (relative) {sv}; raw null direction: {ident.raw_null_words}")
        lines.append(f"  least determined: {ident.words[-1]} (1 sigma {sigma_words(ident.combination_sigma[-1])}; "
                     f"moves the measured normal by {np.rad2deg(ident.normal_effect[-1]):.2g} deg RMS)")
    lines += precision_advice(report) + noise_advice(report)
    lines.append(verdict_text(report.verdict()))
    return "\n".join(lines)


def fit_summaries(report: CalibrationReport) -> list:
    """One :class:`~metrology.report.fit_report.FitSummary` per sensor: its five chart errors
    (zero x, y, z mm; beam tilt e1, e2 deg) fitted to its readings; chi-square against the
    stated noise (``noise_mm``; NaN where none is stated)."""
    cal = report.calibration
    out = []
    for i, name in enumerate(cal.nominal.names):
        th, cov = cal.theta[i], cal.cov[i]
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
        n, noise = int(cal.n_used[i]), float(cal.nominal.noise_mm[i])
        chi2 = n * (cal.residual_rms[i] / noise) ** 2 if noise > 0 else float("nan")
        params = tuple((p, float(v), float(e), "mm") for p, v, e in zip(("x", "y", "z"), th[:3], se[:3]))
        params += tuple((p, float(np.rad2deg(np.arctan(v))), float(np.rad2deg(e)), "deg")
                        for p, v, e in zip(("tilt_e1", "tilt_e2"), th[3:], se[3:]))
        # the nominal's error about the nominal's chart: the certificate and the layout's direction_stderr_deg state
        # the tilt about the calibrated direction's chart, another 1 sigma under the names e1, e2 (issue 51 item 9)
        out.append(FitSummary(f"{name} (zero error, beam tilt about the nominal's e1, e2)", cal.method, n, 5,
                              float(chi2), params, correlations_from_cov(cov, CHART_NAMES), sensor=name))
    return out


def noise_advice(report: CalibrationReport) -> list:
    """A pointer to ``metro diagnose`` when the residuals exceed the stated noise: the model
    adequacy checks of :meth:`CalibrationReport.adequacy` (chi-square of each sensor's residuals
    against ``noise_mm``, dof = readings - 5, one-sided at ``MODEL_ADEQUACY_ALPHA``)."""
    from metrology.calibration.calibrate import MODEL_ADEQUACY_ALPHA

    high = [f"{name} {1e3 * rms:.1f} µm (allowed {1e3 * limit:.1f} µm)"
            for name, rms, limit, p in report.adequacy() if p < MODEL_ADEQUACY_ALPHA]
    if not high:
        return []
    return [f"model adequacy: residuals above the stated noise ({', '.join(high)}; chi-square p < "
            f"{MODEL_ADEQUACY_ALPHA:g}): the model misses something. Run `metro diagnose` on the same files to name it."]


def precision_advice(report: CalibrationReport) -> list:
    """What to do when the poses leave the parameters less precise than the target: one line
    for all sensors (the precision reached, and the pose spread or count that would reach the
    target). Advice, not a failure: the calibration itself is valid."""
    short = [ident for ident in report.identifiability if ident.fix]
    if not short:
        return []
    pse = np.array([ident.predicted_stderr for ident in short])
    z, tilt = pse[:, :3], np.rad2deg(pse[:, 3:])
    fix = short[0].fix
    target = fix["target"]
    ways = [ident.fix["within_range"] for ident in short if ident.fix.get("within_range")]
    lines = [f"precision: 1 sigma up to {np.nanmax(z):.3g} mm (zero points) and {np.nanmax(tilt):.3g} deg (beams) on "
             f"{', '.join(ident.name for ident in short)}, against " + ("your target of " if report.target_set else
                                                                      "the default target of ")
             + f"{target['zero_mm']:g} mm / {target['tilt_deg']:g} deg" + (" (--target-mm, --target-deg)." if
                                                                           report.target_set else
                                                                           " (information; --target-mm and --target-deg "
                                                                           "set one that gates).")]
    now = f"now tilts up to {short[0].tilt_max_deg:.1f} deg, stand-off spread {short[0].standoff_spread_mm:.1f} mm"
    more = max((ident.fix["poses_needed_at_current_spread"] or 0) for ident in short)
    if ways:
        lines.append(f"  to reach it: poses tilted up to {max(w['tilt_max_deg'] for w in ways):g} deg with a stand-off "
                     f"spread of {max(w['standoff_spread_mm'] for w in ways):g} mm ({now}), or about {more} poses "
                     "at the current spread.")
    elif more:
        lines.append(f"  to reach it: about {more} poses at the current spread ({now}); see --json for the scan.")
    return lines


def calibration_warnings(report: CalibrationReport) -> list:
    """What the poses cannot determine at all (rank-deficient or weak combinations): warnings
    for stderr. The precision advice is in :func:`precision_advice`."""
    return [w for ident in report.identifiability for w in ident.warnings
            if "not determined" in w or "weakly determined" in w]


def plot_convergence(report: CalibrationReport, path, convergence=None) -> Path:
    """Write :func:`convergence_figure` to ``path`` atomically (format from the suffix)."""
    save_figure(convergence_figure(report, convergence), path)
    return Path(path)


def convergence_figure(report: CalibrationReport, convergence=None):
    """Convergence of each parameter of each sensor (Figures 7 and 11); returns the figure.

    Parameters
    ----------
    report : CalibrationReport
    convergence : list, optional
        :func:`metrology.calibration.convergence.batch_convergence` output for a batch method
        (computed here when needed).
    """
    cal = report.calibration
    names = cal.nominal.names
    n = len(names)
    plt = pyplot()
    fig, axes = plt.subplots(n, 2, figsize=(10, 2.6 * n), sharex=True, squeeze=False)
    if cal.history:
        for i in range(n):
            h = cal.history[i]
            k = np.arange(1, len(h) + 1)
            for j, p in enumerate(("dx", "dy", "dz")):
                axes[i, 0].plot(k, h[:, j], color=_COLOURS[j], label=p)
            for j, p in enumerate(("dm", "dn", "dq")):
                axes[i, 1].plot(k, h[:, 3 + j], color=_COLOURS[3 + j], label=p)
            if len(cal.n_converged) and cal.n_converged[i] > 0:
                for ax in axes[i]:
                    ax.axvline(cal.n_converged[i], color="0.5", ls=":", lw=1)
            axes[i, 0].set_ylabel(f"{names[i]}\nzero error [mm]")
            axes[i, 1].set_ylabel("direction-vector error [1]")
        title = f"{cal.method}: filter estimate after each measurement (dotted: stopping rule met)"
    else:
        conv = report.convergence if convergence is None else convergence
        for i in range(n):
            k, th, se = conv[i]
            for j, p in enumerate(("x", "y", "z")):
                axes[i, 0].plot(k, th[:, j], color=_COLOURS[j], label=p)
                axes[i, 0].fill_between(k, th[:, j] - se[:, j], th[:, j] + se[:, j], color=_COLOURS[j], alpha=0.2, lw=0)
            for j, p in enumerate(("tilt e1", "tilt e2")):
                y, s = np.rad2deg(np.arctan(th[:, 3 + j])), np.rad2deg(se[:, 3 + j])
                axes[i, 1].plot(k, y, color=_COLOURS[3 + j], label=p)
                axes[i, 1].fill_between(k, y - s, y + s, color=_COLOURS[3 + j], alpha=0.2, lw=0)
            axes[i, 0].set_ylabel(f"{names[i]}\nzero error [mm]")
            axes[i, 1].set_ylabel("beam tilt [deg]")
            tilt = np.rad2deg(np.arctan(th[:, 3:]))
            _settled_ylim(axes[i, 0], k, th[:, :3], se[:, :3])
            _settled_ylim(axes[i, 1], k, tilt, np.rad2deg(se[:, 3:]))
        title = f"{cal.method}: estimate from the first k poses, ±1 σ bands (y range: the last three quarters)"
    for ax in axes.ravel():
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("measurements [count]" if cal.history else "poses used [count]")
    axes[-1, 1].set_xlabel("measurements [count]" if cal.history else "poses used [count]")
    fig.suptitle(title, fontsize=10)
    # each column's legend in a row of its own between the title and the top axes (issue 51, item 12: inside
    # the axes, "upper right", it sat over the title and the data); constrained layout makes room for both
    for c in (0, 1):
        axes[0, c].legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3, frameon=False,
                          borderaxespad=0.2)
    fig.set_layout_engine("constrained")
    return fig


#: the convergence plot's y range is set by the estimates and bands of the poses after this share of
#: the run: the first poses' bands (a few poses, a wide 1 sigma) would otherwise flatten the rest
SETTLED_FROM = 0.25


def _settled_ylim(ax, k, y, s) -> None:
    """Set ``ax``'s y range to cover ``y +- s`` over ``k >= SETTLED_FROM * k.max()`` (a tenth of
    that span as margin); the earlier, wider bands run off the axis."""
    sel = np.asarray(k) >= SETTLED_FROM * np.max(k)
    lo, hi = np.nanmin((y - s)[sel]), np.nanmax((y + s)[sel])
    if np.isfinite(lo) and np.isfinite(hi) and hi > lo:
        pad = 0.1 * (hi - lo)
        ax.set_ylim(lo - pad, hi + pad)


def plot_residuals(report: CalibrationReport, path) -> Path:
    """Write :func:`residuals_figure` to ``path`` atomically (format from the suffix)."""
    save_figure(residuals_figure(report), path)
    return Path(path)


def residuals_figure(report: CalibrationReport):
    """Residuals of the calibrated layout vs reading, incidence angle and pose index; returns the figure."""
    res, inc = residual_table(report.layout, report.dataset.obs)
    d = report.dataset.obs.d
    names = report.layout.names
    plt = pyplot()
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharey=True)
    idx = np.arange(1, len(d) + 1)
    for i, name in enumerate(names):
        c = _COLOURS[i % len(_COLOURS)]
        ok = np.isfinite(res[:, i])
        rms = np.sqrt(np.mean(res[ok, i] ** 2))
        axes[0].plot(d[ok, i], res[ok, i] * 1e3, ".", color=c, label=f"{name} (RMS {rms * 1e3:.1f} µm, stated noise {report.dataset.layout.noise_mm[i] * 1e3:.1f} µm)")
        axes[1].plot(inc[ok, i], res[ok, i] * 1e3, ".", color=c)
        axes[2].plot(idx[ok], res[ok, i] * 1e3, ".-", color=c, lw=0.5)
    axes[0].set_xlabel("reading [mm]")
    axes[1].set_xlabel("incidence angle of the beam on the datum [deg]")
    axes[2].set_xlabel("pose [index]")
    for ax in axes:
        ax.set_ylabel("residual [µm]\n(measured - predicted)")
    for ax in axes:
        ax.axhline(0, color="0.3", lw=0.8)
        ax.grid(True, alpha=0.3)
    axes[0].legend()
    from matplotlib.ticker import MaxNLocator

    axes[2].xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle(f"{report.calibration.method}: reading residuals of the calibrated layout", fontsize=10)
    fig.tight_layout()
    return fig


def check_plot_target(target) -> Path:
    """Refuse a ``--plot`` target before any work (ValueError naming it): a one-figure format
    (.png, .svg), a PDF in a directory that does not exist, a file where a directory is meant."""
    target = Path(target)
    suffix = target.suffix.lower()
    if suffix in (".png", ".svg", ".jpg", ".jpeg"):
        raise ValueError(f"--plot {target}: a {target.suffix} file holds one figure; give a .pdf file "
                         "(one page per figure) or a directory")
    if suffix == ".pdf":
        if target.is_dir() or not target.resolve().parent.is_dir():
            raise ValueError(f"--plot {target}: a directory, or in a directory that does not exist")
    elif target.exists() and not target.is_dir():
        raise ValueError(f"{target}: not a directory")
    return target


def write_calibration_plots(report: CalibrationReport, target) -> list:
    """Write the convergence and residual figures.

    ``target`` ending in ``.pdf``: one PDF file, a page per figure (as ``fit-plane --plot``
    writes one file). Otherwise a directory (created if missing) receiving
    ``convergence.png`` and ``residuals.png``. Each file is written atomically; returns
    the paths written.
    """
    target = check_plot_target(target)
    if target.suffix.lower() == ".pdf":
        from matplotlib.backends.backend_pdf import PdfPages

        from metrology.io.atomic import atomic_path
        from metrology.report.style import close

        figs = [convergence_figure(report), residuals_figure(report)]
        try:
            with atomic_path(target) as tmp, PdfPages(tmp, metadata={"Creator": "metro calibrate"}) as pdf:
                for fig in figs:
                    pdf.savefig(fig)
        finally:
            for fig in figs:
                close(fig)
        return [target]
    target.mkdir(parents=True, exist_ok=True)
    return [plot_convergence(report, target / "convergence.png"), plot_residuals(report, target / "residuals.png")]

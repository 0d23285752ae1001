"""Figures of a calibration and a validation (PNG, written atomically).

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

from metrology.io.atomic import atomic_path
from metrology.report.plots import pyplot

__all__ = ["plot_convergence", "plot_residuals", "plot_validation", "write_calibration_plots"]

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")


def _save(fig, path):
    plt = pyplot()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)


def plot_convergence(report, path, convergence=None) -> Path:
    """Convergence of each parameter of each sensor (Figures 7 and 11).

    Parameters
    ----------
    report : CalibrationReport
    path : str or Path, PNG
    convergence : list, optional
        :func:`metrology.calibration.batch_convergence` output for a batch method
        (computed here when needed).
    """
    from metrology.calibration.calibrate import batch_convergence

    cal = report.calibration
    names = cal.nominal.names
    n = len(names)
    plt = pyplot()
    fig, axes = plt.subplots(n, 2, figsize=(11, 2.4 * n), sharex=True, squeeze=False)
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
            axes[i, 1].set_ylabel("direction error [-]")
        title = f"{cal.method}: filter estimate after each measurement (dotted: stopping rule met)"
    else:
        conv = batch_convergence(cal.nominal, report.dataset.obs, cal.method) if convergence is None else convergence
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
        title = f"{cal.method}: estimate from the first k poses, +-1 sigma bands"
    for ax in axes.ravel():
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8, ncol=3)
    axes[0, 1].legend(loc="upper right", fontsize=8, ncol=3)
    axes[-1, 0].set_xlabel("measurements" if cal.history else "poses used")
    axes[-1, 1].set_xlabel("measurements" if cal.history else "poses used")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return Path(path)


def plot_residuals(report, path) -> Path:
    """Residuals of the calibrated layout vs reading, incidence angle and pose index."""
    from metrology.calibration.calibrate import residual_table

    res, inc = residual_table(report.layout, report.dataset.obs)
    d = report.dataset.obs.d
    names = report.layout.names
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    idx = np.arange(1, len(d) + 1)
    for i, name in enumerate(names):
        c = _COLOURS[i % len(_COLOURS)]
        ok = np.isfinite(res[:, i])
        rms = np.sqrt(np.mean(res[ok, i] ** 2))
        axes[0].plot(d[ok, i], res[ok, i] * 1e3, ".", color=c, label=f"{name} (RMS {rms * 1e3:.1f} um)")
        axes[1].plot(inc[ok, i], res[ok, i] * 1e3, ".", color=c)
        axes[2].plot(idx[ok], res[ok, i] * 1e3, ".-", color=c, lw=0.5)
    axes[0].set_xlabel("reading [mm]")
    axes[1].set_xlabel("incidence angle of the beam on the datum [deg]")
    axes[2].set_xlabel("pose index")
    axes[0].set_ylabel("residual, measured - predicted [um]")
    for ax in axes:
        ax.axhline(0, color="0.3", lw=0.8)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{report.calibration.method}: reading residuals of the calibrated layout", fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return Path(path)


def plot_validation(vreport, path) -> Path:
    """Angular deviation per pose, one series per layout (Figure 12)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4))
    x = np.arange(1, len(vreport.pose_id) + 1)
    markers = ("o", "s", "^", "D", "v")
    for k, label in enumerate(vreport.labels):
        s = vreport.stats_deg(k)
        ax.plot(x, np.rad2deg(vreport.deviation[k]), marker=markers[k % len(markers)], ms=4,
                color=_COLOURS[k % len(_COLOURS)],
                label=f"{label}: max {s['max_deg']:.4f}, mean {s['mean_deg']:.4f}, std {s['std_deg']:.4f} deg")
    ax.set_xlabel("pose")
    ax.set_ylabel("angular deviation of the normal [deg]")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("measured normal vs datum normal (TCS)", fontsize=10)
    fig.tight_layout()
    _save(fig, path)
    return Path(path)


def write_calibration_plots(report, directory) -> list:
    """Write ``convergence.png`` and ``residuals.png`` into ``directory`` (created if
    missing); return their paths."""
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise ValueError(f"{directory}: not a directory")
    directory.mkdir(parents=True, exist_ok=True)
    return [plot_convergence(report, directory / "convergence.png"), plot_residuals(report, directory / "residuals.png")]

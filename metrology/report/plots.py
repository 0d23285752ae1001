"""Figures of the reproduction (the paper's Figures 7 and 8). matplotlib is imported lazily."""

from __future__ import annotations

import numpy as np

from metrology.io.atomic import atomic_path

__all__ = ["figure7", "figure8", "pyplot", "save_figure"]

#: panel titles of Figure 7: zero-point errors in mm; dm, dn, dq are changes of the components of
#: the unit beam direction, dimensionless ([1])
RAW_LABELS = ("dx [mm]", "dy [mm]", "dz [mm]", "dm [1]", "dn [1]", "dq [1]")


#: legend words of Figure 8's series (the estimators' names otherwise)
METHOD_WORDS = {"before": "nominal layout (before)", "true": "true parameters (noise floor)",
                "ekf_paper": "paper's EKF", "method1": "paper's method 1", "lsq": "least squares (lsq)",
                "iekf": "iterated EKF (iekf)", "ekf": "EKF (ekf)"}


def pyplot():
    """``matplotlib.pyplot`` on the headless Agg backend, in metro's one style
    (:mod:`metrology.report.style`)."""
    from metrology.report.style import pyplot as styled

    return styled()


def save_figure(fig, path, dpi=110) -> None:
    """Write ``fig`` to ``path`` atomically (the format from the suffix) and close it, even
    when the write fails: the one way every report writes a figure."""
    plt = pyplot()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        plt.close(fig)


def figure7(history, true_errors, names, path, title="Paper's EKF: estimated parameter errors"):
    """Estimated errors against the measurement index, one panel per parameter.

    Parameters
    ----------
    history : list of (k_i, 6) float, per sensor, raw errors (mm; unitless for directions)
    true_errors : (n, 6) float, the errors that generated the data (dashed lines)
    names : sequence of str, sensor names
    path : output PNG path (written atomically)
    """
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for j, ax in enumerate(axes.flat):
        for i, (h, name) in enumerate(zip(history, names)):
            c = colours[i % len(colours)]
            ax.plot(np.arange(1, len(h) + 1), h[:, j], color=c, lw=1.2, label=name)
            ax.axhline(true_errors[i, j], color=c, ls="--", lw=0.8)
        ax.set_title(RAW_LABELS[j])
        ax.set_ylabel(f"estimated error {RAW_LABELS[j].split()[1]}")
    for ax in axes[1]:
        ax.set_xlabel("measurement [count]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"{title} (dashed: truth)")
    fig.tight_layout()
    save_figure(fig, path)


def figure8(deviation_deg, path, title="Angular deviation of the measured normal"):
    """Angular deviation per workpiece pose for each method (log scale).

    Parameters
    ----------
    deviation_deg : dict method -> (m,) float, deg
    path : output PNG path (written atomically)
    """
    from metrology.report.style import plain_log_ticks

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.8))
    markers = "osv^D*xP"
    for k, (name, dev) in enumerate(deviation_deg.items()):
        ax.plot(np.arange(1, len(dev) + 1), dev, marker=markers[k % len(markers)], ms=4, lw=1,
                label=METHOD_WORDS.get(name, name))
    from matplotlib.ticker import MaxNLocator

    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("workpiece pose [index]")
    ax.set_ylabel("angular deviation [deg]")
    ax.legend(fontsize=8, ncol=4)
    ax.set_title(title)
    plain_log_ticks(ax)
    fig.tight_layout()
    save_figure(fig, path)

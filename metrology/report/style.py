"""The one plotting style of every metro figure (matplotlib, imported lazily).

Every figure is made through :func:`pyplot` (or after :func:`apply_style` where a bare
``matplotlib.figure.Figure`` is used), so all commands share fonts, grid, colours and
resolution. Axis labels carry their unit in brackets: ``reading [mm]``, ``dm [1]`` for a
component of a unit vector.
"""

from __future__ import annotations

__all__ = ["RC", "apply_style", "pyplot", "close", "plain_log_ticks"]

#: the rcParams every figure is drawn with
RC = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 8,
    "legend.framealpha": 0.85,
    "axes.grid": True,
    "axes.grid.which": "both",
    "grid.alpha": 0.3,
    "grid.linewidth": 0.6,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "lines.linewidth": 1.2,
    "lines.markersize": 4,
    "image.cmap": "viridis",
    "savefig.dpi": 110,
    "figure.dpi": 100,
    "pdf.fonttype": 42,  # TrueType in PDFs: text stays text
    "svg.fonttype": "none",
}


def apply_style() -> None:
    """Set :data:`RC` on matplotlib (the Agg backend, no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    matplotlib.rcParams.update(RC)


def pyplot():
    """``matplotlib.pyplot`` on the headless Agg backend, with :data:`RC` applied."""
    apply_style()
    import matplotlib.pyplot as plt

    return plt


def close(fig) -> None:
    """Release a figure made by :func:`pyplot` (a bare ``Figure`` needs nothing)."""
    import matplotlib.pyplot as plt

    plt.close(fig)


def plain_log_ticks(ax) -> None:
    """A log y axis labelled in plain numbers (0.01, 0.1, 1, not 10^-2): the minor ticks too
    when the axis spans less than a decade (otherwise too many)."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    plain = FuncFormatter(lambda v, _: f"{v:g}")
    ax.yaxis.set_major_formatter(plain)
    lo, hi = ax.get_ylim()
    ax.yaxis.set_minor_formatter(plain if lo > 0 and hi / lo < 10 else NullFormatter())

"""The panel map of ``metro measure --panel/--points``: the hole table's holes over the panel, each
coloured by its judged angle (what an engineer looks at first: where on the skin the holes lean)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PanelMap", "panel_map_figure", "NOT_MEASURED_COLOUR", "FAILS_COLOUR", "PANEL_FILL", "PANEL_EDGE"]

#: the marker colours of holes without a judged angle and of holes that fail; the panel's box's fill and edge
NOT_MEASURED_COLOUR = "#9e9e9e"
PANEL_FILL, PANEL_EDGE = "#f2f2f2", "#bdbdbd"
FAILS_COLOUR = "#d62728"


@dataclass(frozen=True)
class PanelMap:
    """The holes of a hole table as a run measured them.

    Attributes
    ----------
    ids : tuple of str, the table's hole ids
    point : (m, 3) float, mm, panel frame, the nominal drill points
    angle_deg : (m,) float, deg, the judged angle of the hole's last pass in the log (NaN: not in the
        log, or not measured)
    status : (m,) str, its status ("" : not in the log)
    source : str, the panel (or the table) as the report names it
    box : ((3,), (3,)) float, mm, panel frame, the panel's vertices' lowest and highest corner (None: a table
        alone, or a STEP panel, not tessellated again for a figure)
    """

    ids: tuple
    point: np.ndarray
    angle_deg: np.ndarray
    status: np.ndarray
    source: str
    box: tuple | None = None


def _axes(point):
    """The two panel-frame coordinates the holes spread most along (x, y for a skin in its xy plane)."""
    spread = np.ptp(point, axis=0) if len(point) else np.ones(3)
    a, b = sorted(np.argsort(spread)[::-1][:2])
    return int(a), int(b)


def panel_map_figure(m: PanelMap, tolerance_deg: float):
    """A matplotlib figure: the holes over the panel's plane, coloured by the judged angle (0 to the
    tolerance; to the largest angle where all are below half of it); holes that fail ringed red; holes not measured (or not in the log) grey crosses."""
    from metrology.report.style import pyplot

    plt = pyplot()
    i, j = _axes(m.point)
    x, y = m.point[:, i], m.point[:, j]
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    if m.box is not None:  # the panel under its holes: where on the skin they are
        from matplotlib.patches import Rectangle

        lo, hi = (np.asarray(c, float) for c in m.box)
        ax.add_patch(Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j], facecolor=PANEL_FILL,
                               edgecolor=PANEL_EDGE, linewidth=1.0, zorder=1))
        ax.update_datalim([(lo[i], lo[j]), (hi[i], hi[j])])
    judged = np.isfinite(m.angle_deg)
    top = float(np.max(m.angle_deg[judged])) if judged.any() else tolerance_deg
    vmax = tolerance_deg if top > tolerance_deg / 2 else max(top, 1e-3)  # small angles: the scale spans them
    sc = ax.scatter(x[judged], y[judged], c=m.angle_deg[judged], cmap="viridis", vmin=0.0, vmax=vmax,
                    s=22, edgecolors="none", zorder=3)
    fails = m.status == "fails"
    if fails.any():
        ax.scatter(x[fails], y[fails], s=60, facecolors="none", edgecolors=FAILS_COLOUR, linewidths=1.2, zorder=4,
                   label=f"fails ({int(fails.sum())})")
    if (~judged).any():
        ax.scatter(x[~judged], y[~judged], marker="x", s=18, color=NOT_MEASURED_COLOUR, zorder=2,
                   label=f"not measured or not in the log ({int((~judged).sum())})")
    cb = fig.colorbar(sc, ax=ax, extend="max" if top > vmax else "neither", orientation="horizontal",
                      location="bottom", pad=0.18, fraction=0.06, aspect=40)
    cb.ax.locator_params(nbins=5)
    cb.set_label("judged angle [deg]" + ("" if vmax == tolerance_deg else f" (tolerance {tolerance_deg:g})"))
    names = "xyz"
    ax.set_xlabel(f"panel {names[i]} [mm]")
    ax.set_ylabel(f"panel {names[j]} [mm]")
    ax.set_aspect("equal", adjustable="datalim")
    title = f"{m.source}: {int(judged.sum())} of {len(m.ids)} holes judged"
    if fails.any() or (~judged).any():
        ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=2, frameon=False, title=title)
    else:
        ax.set_title(title)
    fig.tight_layout()
    return fig

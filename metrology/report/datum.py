"""Figures of a datum-plane fit: residuals over the plane and their histogram."""

from __future__ import annotations

from pathlib import Path
import numpy as np
from metrology.datum.result import PlaneFit


_PLOT_SUFFIXES = {".png", ".pdf", ".svg"}


_PLOT_MAX_POINTS = 200_000


def plot_residuals(points, fit: PlaneFit, path) -> None:
    """Write a residual map over the plate (inliers coloured by residual, outliers grey).

    Parameters
    ----------
    points : (m, 3) float, mm, cloud frame
        The cloud ``fit`` was fitted to.
    fit : PlaneFit
    path : str or os.PathLike
        ``.png``, ``.pdf`` or ``.svg``; written as is (callers make it atomic).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    pts = np.asarray(points, dtype=float)
    if len(pts) > _PLOT_MAX_POINTS:  # a deterministic thinning, for the figure only
        pts = pts[np.sort(np.random.default_rng(fit.seed).choice(len(pts), _PLOT_MAX_POINTS, replace=False))]
    inl = fit.inliers(pts)
    r = fit.residuals(pts)
    uv = (pts - fit.centroid) @ fit.axes.T
    fig = Figure(figsize=(8, 6.2), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    lim = float(np.max(np.abs(r[inl]))) if inl.any() else 1.0
    ax.scatter(uv[~inl, 0], uv[~inl, 1], s=8, c="0.6", marker="x", linewidths=0.6, label=f"outliers ({fit.n_points - fit.n_inliers})")
    size = 4 if inl.sum() > 20000 else 12
    sc = ax.scatter(uv[inl, 0], uv[inl, 1], s=size, c=r[inl], cmap="RdBu_r", vmin=-lim, vmax=lim, linewidths=0)
    fig.colorbar(sc, ax=ax, label="residual to the plane (mm, + along the normal)")
    if fit.form is not None and inl.sum() >= 7:
        gu = np.linspace(uv[inl, 0].min(), uv[inl, 0].max(), 60)
        gv = np.linspace(uv[inl, 1].min(), uv[inl, 1].max(), 60)
        U, V = np.meshgrid(gu, gv)
        cs = ax.contour(U, V, fit.form.evaluate(U, V), levels=8, colors="k", linewidths=0.6, alpha=0.6)
        ax.clabel(cs, fmt="%.4f", fontsize=6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("u (mm, in-plane, from the centroid)")
    ax.set_ylabel("v (mm, in-plane)")
    form = ""
    if fit.form is not None:
        form = f", quadratic form P-V {fit.form.pv:.4f} mm (p = {fit.form.p_value:.2g})"
    ax.set_title(
        f"{Path(fit.source).name or 'cloud'}: {fit.n_inliers}/{fit.n_points} inliers, RMS {fit.rms:.4f} mm, "
        f"flatness {fit.flatness:.4f} mm{form}",
        fontsize=9,
    )
    if (~inl).any():
        ax.legend(loc="upper right", fontsize=7)
    fig.savefig(path, dpi=130)

"""Text and figures of ``metro fit-plane``: the plane report and the residual map."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from metrology.datum import PlaneFit

__all__ = ["format_plane_fit", "plot_residuals", "residual_map_figure"]


def format_plane_fit(fit: PlaneFit) -> str:
    """The readable report of a :class:`metrology.datum.PlaneFit`."""
    d = fit.to_dict()
    n = d["normal"]
    lines = [
        f"datum plane of {d['source']} ({d['format']}, {d['n_points']} points, cloud frame, mm)",
        f"  normal (A, B, C)     {n[0]: .10f} {n[1]: .10f} {n[2]: .10f}",
        f"  offset D             {d['offset']: .6f} mm",
        "  convention           A^2 + B^2 + C^2 = 1, D <= 0 (the normal points from the origin towards the plane)",
        f"  inliers              {d['n_inliers']} of {d['n_points']} ({100 * d['inlier_ratio']:.2f} %)"
        f" within {d['threshold_mm']:.4g} mm ({d['threshold_source']})",
        f"  residuals (inliers)  RMS {d['rms_mm']:.5f} mm, max |r| {d['max_abs_residual_mm']:.5f} mm,"
        f" flatness (P-V) {d['flatness_mm']:.5f} mm",
    ]
    if d["normal_sigma_deg"] is None:
        lines.append("  uncertainty (1 sd)   not available: 3 inliers leave no residual degrees of freedom")
    else:
        lines.append(
            f"  uncertainty (1 sd)   normal {d['normal_sigma_deg']:.3g} deg, offset D {d['offset_sigma_mm']:.3g} mm"
            f" ({d['offset_sigma_at_centroid_mm']:.3g} mm at the centroid), noise {d['noise_sigma_mm']:.4g} mm"
        )
    c = d["centroid"]
    lines.append(f"  centroid             {c[0]:.4f} {c[1]:.4f} {c[2]:.4f} mm")
    f = d["form"]
    if f is None:
        lines.append("  form (quadratic)     not computed: fewer than 7 inliers, or they do not span the plane")
    else:
        verdict = "SIGNIFICANT: the datum is not flat" if f["significant"] else "not significant"
        p = f["p_value"]
        ptxt = f"{p:.3g}" if p >= 1e-300 else "< 1e-300"
        fstat = f["f_statistic"]
        lines.append(
            f"  form (quadratic)     P-V {f['pv_mm']:.5f} mm, F({f['dof'][0]}, {f['dof'][1]}) = "
            f"{fstat:.4g}, p = {ptxt}: {verdict} (alpha {f['alpha']:g})"
        )
        co, sd = f["coefficients"], f["sigma"]
        terms = []
        for key, label in (("cuu_per_mm", "u^2"), ("cuv_per_mm", "uv"), ("cvv_per_mm", "v^2")):
            terms.append(f"{label} {co[key]:.3e} +- {sd[key]:.1e}" if math.isfinite(sd[key]) else f"{label} {co[key]:.3e}")
        lines.append(f"                       {', '.join(terms)} /mm (u, v: in-plane axes from the centroid)")
    return "\n".join(lines)


_PLOT_MAX_POINTS = 200_000


def plot_residuals(points, fit: PlaneFit, path) -> None:
    """Write :func:`residual_map_figure` to ``path`` (``.png``, ``.pdf``, ``.svg``; written as
    is, callers make it atomic)."""
    residual_map_figure(points, fit).savefig(path, dpi=130)


def residual_map_figure(points, fit: PlaneFit):
    """A residual map over the plate (inliers coloured by residual, outliers grey); returns
    a bare matplotlib ``Figure`` in metro's style.

    Parameters
    ----------
    points : (m, 3) float, mm, cloud frame
        The cloud ``fit`` was fitted to.
    fit : PlaneFit
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from metrology.report.style import apply_style

    apply_style()

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
    fig.colorbar(sc, ax=ax, label="residual to the plane [mm] (+ along the normal)")
    if fit.form is not None and inl.sum() >= 7:
        gu = np.linspace(uv[inl, 0].min(), uv[inl, 0].max(), 60)
        gv = np.linspace(uv[inl, 1].min(), uv[inl, 1].max(), 60)
        U, V = np.meshgrid(gu, gv)
        if fit.form.significant:  # a form found: its contours drawn and labelled
            cs = ax.contour(U, V, fit.form.evaluate(U, V), levels=8, colors="k", linewidths=0.6, alpha=0.6)
            ax.clabel(cs, fmt="%.4f", fontsize=9)
        else:  # not significant: faint, unlabelled (a form below the test's reach, not a finding)
            ax.contour(U, V, fit.form.evaluate(U, V), levels=8, colors="0.5", linewidths=0.4, alpha=0.35,
                       linestyles="dotted")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("u [mm] (in-plane, from the centroid)")
    ax.set_ylabel("v [mm] (in-plane)")
    form = ""
    if fit.form is not None:
        form = (f"\nquadratic form P-V {fit.form.pv:.4f} mm (p = {fit.form.p_value:.2g}"
                + ("" if fit.form.significant else ", not significant: dotted") + ")")
    ax.set_title(
        f"{Path(fit.source).name or 'cloud'}: {fit.n_inliers}/{fit.n_points} inliers, RMS {fit.rms:.4f} mm, "
        f"flatness {fit.flatness:.4f} mm{form}",
        fontsize=9,
    )
    if (~inl).any():
        ax.legend(loc="upper right", fontsize=9)
    return fig

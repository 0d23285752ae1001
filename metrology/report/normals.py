"""Words and figures of a normals run: summary, recommendation, per-point table, error map."""

from __future__ import annotations

import csv
import math
import numpy as np
from metrology.core.normals import angle_between
from metrology.core.stats import describe
from metrology.panel.attitude import STATUS
from metrology.panel.mesh import plane_axes
from metrology.panel.run import NormalsRun


def summarize(run: NormalsRun) -> dict:
    """Summary per method, point status counts, and a recommendation.

    Returns
    -------
    dict with ``plane`` and ``sphere`` (``n``, ``max_deg``, ``mean_deg``, ``std_deg``,
    ``p95_deg``, ``within_tolerance``, and the loop's ``iterations_mean``,
    ``iterations_max``, ``converged``, ``final_max_deg``, ``final_mean_deg``),
    ``status`` (counts), ``recommendation`` (``method`` and ``text``), ``info``, and for
    generated panels ``mesh_vs_analytic_max_deg`` (the mesh reference normal against the
    analytic normal: the tessellation error).
    """
    tol = math.radians(run.info["tolerance_deg"])
    out = {}
    for name, err in (("plane", run.err_plane), ("sphere", run.err_sphere)):
        s = describe(np.degrees(err), p95=True, count=True)
        fin = np.isfinite(err)
        s["within_tolerance"] = float(np.mean(err[fin] < tol)) if np.any(fin) else math.nan
        lp = run.loop.get(name)
        if lp is not None:
            sel = run.status == "ok"
            it = lp["iterations"][sel]
            fd = lp["final_dev"][sel]
            s.update({"iterations_mean": float(it.mean()), "iterations_max": int(it.max()),
                      "converged": float(lp["converged"][sel].mean()),
                      "lost": int(lp["lost"][sel].sum()),
                      "final_max_deg": float(np.degrees(np.nanmax(fd))) if np.any(np.isfinite(fd)) else math.nan,
                      "final_mean_deg": float(np.degrees(np.nanmean(fd))) if np.any(np.isfinite(fd)) else math.nan})
        out[name] = s
    if run.n_analytic is not None:
        sel = run.status == "ok"
        dev = angle_between(run.n_true[sel], run.n_analytic[sel], oriented=True)
        out["mesh_vs_analytic_max_deg"] = float(np.degrees(dev.max())) if len(dev) else math.nan
    counts = {k: int(np.sum(run.status == k)) for k in STATUS}
    out["status"] = counts
    out["recommendation"] = _recommend(run, out, tol)
    out["info"] = run.info
    return out


def _recommend(run, summ, tol):
    ok = np.isfinite(run.err_plane) & np.isfinite(run.err_sphere)
    if not np.any(ok):
        return {"method": None, "text": "no drilling point could be measured"}
    ep, es = np.degrees(run.err_plane[ok]), np.degrees(run.err_sphere[ok])
    sp, ss = summ["plane"], summ["sphere"]
    # decide on the worst case first (a hole out of tolerance is scrap), then the mean
    score_p = (sp["p95_deg"], sp["mean_deg"])
    score_s = (ss["p95_deg"], ss["mean_deg"])
    method = "plane" if score_p <= score_s else "sphere"
    other = "sphere" if method == "plane" else "plane"
    e_best, e_other = (ep, es) if method == "plane" else (es, ep)
    wins = e_other < e_best - 1e-6
    n_w = int(wins.sum())
    text = (f"micro-{method}: 95th percentile {summ[method]['p95_deg']:.4f} deg, mean {summ[method]['mean_deg']:.4f} deg "
            f"against micro-{other}'s {summ[other]['p95_deg']:.4f} / {summ[other]['mean_deg']:.4f} deg")
    if n_w:
        pts = run.points[ok][wins]
        gain = float(np.median(e_best[wins] - e_other[wins]))
        text += (f"; micro-{other} is better at {n_w} of {int(ok.sum())} points (median gain {gain:.4f} deg, "
                 f"x {pts[:, 0].min():.0f}..{pts[:, 0].max():.0f}, y {pts[:, 1].min():.0f}..{pts[:, 1].max():.0f}, "
                 f"z {pts[:, 2].min():.0f}..{pts[:, 2].max():.0f} mm)")
    else:
        text += f"; micro-{other} is not better at any point"
    frac = summ[method]["within_tolerance"]
    text += f"; {100 * frac:.1f} % of first measurements within {math.degrees(tol):g} deg"
    return {"method": method, "text": text, "other_wins": n_w}


def per_point_rows(run: NormalsRun) -> list:
    """Per-point records (plain dicts; degrees at this edge) for CSV/JSON output."""
    rows = []
    for i, label in enumerate(run.labels):
        r = {"label": label, "status": run.status[i], "detail": run.detail[i],
             "x": run.points[i, 0], "y": run.points[i, 1], "z": run.points[i, 2],
             "off_mm": run.off_mm[i], "initial_tilt_deg": math.degrees(run.initial_tilt[i])}
        nm = run.n_true[i]
        r.update({"n_mesh_x": nm[0], "n_mesh_y": nm[1], "n_mesh_z": nm[2]})
        if run.n_analytic is not None:
            na = run.n_analytic[i]
            r.update({"n_analytic_x": na[0], "n_analytic_y": na[1], "n_analytic_z": na[2]})
        for name, n, e in (("plane", run.n_plane, run.err_plane), ("sphere", run.n_sphere, run.err_sphere)):
            r.update({f"{name}_nx": n[i, 0], f"{name}_ny": n[i, 1], f"{name}_nz": n[i, 2], f"{name}_err_deg": math.degrees(e[i])})
        r["sphere_radius_mm"] = run.sphere_radius[i]
        for name in ("plane", "sphere"):
            lp = run.loop.get(name)
            if lp is not None:
                r.update({f"{name}_theta_deg": math.degrees(lp["theta"][i]), f"{name}_phi_deg": math.degrees(lp["phi"][i]),
                          f"{name}_iterations": int(lp["iterations"][i]), f"{name}_converged": bool(lp["converged"][i]),
                          f"{name}_final_dev_deg": math.degrees(lp["final_dev"][i])})
        rows.append(r)
    return rows


def per_point_text(run: NormalsRun, fmt: str) -> str:
    """The per-point table as CSV (``fmt="csv"``) or JSON (``fmt="json"``) text."""
    import io
    import json

    rows = per_point_rows(run)

    def clean(v):
        if isinstance(v, (bool, np.bool_)):
            return bool(v)
        if isinstance(v, (float, np.floating)):
            return float(v) if math.isfinite(v) else None
        if isinstance(v, (np.integer,)):
            return int(v)
        return v

    if fmt == "json":
        return json.dumps([{k: clean(v) for k, v in r.items()} for r in rows], indent=1) + "\n"
    keys = list(rows[0].keys()) if rows else []
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(keys)
    for r in rows:
        out = []
        for k in keys:
            v = clean(r.get(k))
            out.append("" if v is None else (f"{v:.9g}" if isinstance(v, float) else v))
        w.writerow(out)
    return buf.getvalue()


def plot_error_map(run: NormalsRun, tolerance_deg: float) -> bytes:
    """:func:`error_map_figure` as PNG bytes (110 dpi)."""
    import io

    from metrology.report.style import close

    fig = error_map_figure(run, tolerance_deg)
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=110)
    finally:
        close(fig)
    return buf.getvalue()


def error_map_figure(run: NormalsRun, tolerance_deg: float):
    """Both methods' errors over the panel (its best-fit plane), each on its own colour scale
    (its own smallest to largest error: one method's larger errors do not darken the other's map), the
    points over the tolerance ringed, the points not measured as grey × where there are any;
    returns the figure."""
    from metrology.report.plots import pyplot

    plt = pyplot()

    pts = run.points
    c = pts.mean(axis=0)
    n = np.linalg.svd(pts - c, full_matrices=False)[2][-1] if len(pts) >= 3 else np.array([0.0, 0.0, 1.0])
    n = n if np.all(np.isfinite(n)) and np.linalg.norm(n) > 0.5 else np.array([0.0, 0.0, 1.0])
    uv = (pts - c) @ np.vstack(plane_axes(n)).T  # the axes of panel_plane
    fig, axes = plt.subplots(2, 1, figsize=(8, 9), constrained_layout=True)
    ep, es = np.degrees(run.err_plane), np.degrees(run.err_sphere)
    for ax, e, name in ((axes[0], ep, "micro-plane"), (axes[1], es, "micro-sphere")):
        ok = np.isfinite(e)
        lo, hi = (float(np.min(e[ok])), float(np.max(e[ok]))) if np.any(ok) else (0.0, 1.0)
        sc = ax.scatter(uv[ok, 0], uv[ok, 1], c=e[ok], cmap="viridis", vmin=lo, vmax=hi if hi > lo else lo + 1e-6, s=18)
        fig.colorbar(sc, ax=ax, label=f"{name} normal error [deg]", shrink=0.9)
        big = ok & (e > tolerance_deg)
        ax.scatter(uv[big, 0], uv[big, 1], facecolors="none", edgecolors="tab:red", s=60, linewidths=1.2,
                   label=f"over tolerance (> {tolerance_deg:g} deg): {int(big.sum())}")
        if np.any(~ok):
            ax.scatter(uv[~ok, 0], uv[~ok, 1], marker="x", c="0.35", s=22, linewidths=1.0,
                       label=f"not measured: {int((~ok).sum())}")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
        fin = e[ok]
        stats = f"max {fin.max():.3f}, mean {fin.mean():.3f} deg" if len(fin) else "no point"
        ax.set_title(f"{name}: {stats} (own colour scale)")
        ax.set_xlabel("u [mm]")  # short: wrapped on a phone's figure it ran into the legend beneath
        ax.set_ylabel("v [mm] (best-fit plane)")
        ax.set_aspect("equal")
        ax.grid(False)
    return fig


def summary_text(summary: dict) -> str:
    """The human summary table of :func:`normals_job`."""
    lines = [f"{'method':<8} {'n':>5} {'max_deg':>9} {'mean_deg':>9} {'std_deg':>9} {'p95_deg':>9} {'in_tol':>7} {'iter':>5} {'final_max':>9}"]
    for name in ("plane", "sphere"):
        s = summary[name]
        lines.append(f"{name:<8} {s['n']:>5d} {s['max_deg']:>9.4f} {s['mean_deg']:>9.4f} {s['std_deg']:>9.4f} {s['p95_deg']:>9.4f} "
                     f"{100 * s['within_tolerance']:>6.1f}% {s.get('iterations_mean', math.nan):>5.2f} {s.get('final_max_deg', math.nan):>9.4f}")
    bad = {k: v for k, v in summary["status"].items() if k != "ok" and v}
    if bad:
        lines.append("not measured: " + ", ".join(f"{v} {STATUS[k]}" for k, v in bad.items()))
    if summary.get("grid_dropped"):
        lines.append(f"grid: {summary['grid_dropped']} nodes left out, the head's footprint would cross a crease, "
                     f"a hole or the panel boundary")
    info = summary["info"]
    if str(info.get("beams", "facets")).startswith("smooth"):
        lines.append(f"beams hit the smooth surface the mesh tessellates ({info['beams']})")
    lines.append(f"engine {info['engine']}, stand-off {info['standoff_mm']:.3f} mm, tilt {info['tilt_deg']:g} deg, "
                 f"footprint {info['footprint_mm']:.1f} mm, units {info['units']}, reference normal: {info['reference_normal']}")
    fac = info.get("reference_faceting", {})
    if fac.get("used"):
        lines.append(f"reference faceting (its own uncertainty): max {fac['angle_max_deg']:.4f} deg, chord max "
                     f"{fac['chord_max_mm']:.2g} mm")
    lines.append("recommendation: " + summary["recommendation"]["text"])
    return "\n".join(lines)

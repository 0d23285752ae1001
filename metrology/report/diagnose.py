"""Figures of a diagnosis: base residuals against every covariate, and the named cause before and after."""

from __future__ import annotations

import numpy as np
from metrology.diagnosis.decide import Diagnosis


def plot_report(diag: Diagnosis, out_dir) -> list:
    """Residual plots that made the case, before and after; returns the files written."""
    from pathlib import Path

    from metrology.io.atomic import atomic_path
    from metrology.report.plots import pyplot

    plt = pyplot()

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    P = diag.plot_data
    base, cov, names, d0 = P.base, P.cov, P.names, P.d0
    files = []
    p, n = base.residual.shape
    variables = {
        "d_mm": d0, "incidence_deg": np.rad2deg(np.arccos(np.clip(cov.cos_inc, -1, 1))),
        "time_h": np.broadcast_to(cov.time_h[:, None], (p, n)), "temp_c": np.broadcast_to(cov.temp_c[:, None], (p, n)),
        "spot_s_mm": cov.spot_st[..., 0], "spot_t_mm": cov.spot_st[..., 1],
        "pose_index": np.broadcast_to(np.arange(p, dtype=float)[:, None], (p, n)),
    }
    variables = {k: v for k, v in variables.items() if np.all(np.isfinite(v))}
    # overview: base residuals against every covariate
    fig, axes = plt.subplots(n, len(variables), figsize=(2.6 * len(variables), 2.0 * n), squeeze=False, sharey="row")
    for i in range(n):
        for j, (key, X) in enumerate(variables.items()):
            ax = axes[i, j]
            ax.plot(X[:, i], base.residual[:, i] * 1e3, ".", ms=3)
            ax.axhline(0, color="k", lw=0.5)
            if i == n - 1:
                ax.set_xlabel(key)
            if j == 0:
                ax.set_ylabel(f"{names[i]} residual um")
    fig.suptitle("base model: residuals against each variable")
    fig.tight_layout()
    f1 = out / "residuals_base.png"
    with atomic_path(f1) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    files.append(str(f1))
    best = P.best
    if best is not None:
        f = best.fit
        comp = f.components[0]
        key = comp.plot_key  # the registry entry names the covariate
        cols = list(comp.sensors) if comp.sensors else list(range(n))
        fig, axes = plt.subplots(len(cols), 2, figsize=(9, 2.4 * len(cols)), squeeze=False, sharey="row")
        X = variables.get(key, variables["pose_index"])
        term = comp.evaluate(comp.values, d0, cov)
        for r, i in enumerate(cols):
            a0, a1 = axes[r]
            a0.plot(X[:, i], base.residual[:, i] * 1e3, ".", ms=3, label="base residual")
            order = np.argsort(X[:, i])
            if comp.name not in ("pose_error", "outliers"):
                a0.plot(X[order, i], (term[order, i] - np.nanmean(term[:, i]) + np.nanmean(base.residual[:, i])) * 1e3,
                        "-", color="C3", label=f"fitted {comp.name}")
            a1.plot(X[:, i], f.residual[:, i] * 1e3, ".", ms=3, color="C2")
            for a in (a0, a1):
                a.axhline(0, color="k", lw=0.5)
                a.set_xlabel(key)
            a0.set_ylabel(f"{names[i]} um")
            a0.set_title("before (base)" if r == 0 else "")
            a1.set_title(f"after ({comp.label})" if r == 0 else "")
            a0.legend(fontsize=7)
        fig.tight_layout()
        f2 = out / "residuals_named.png"
        with atomic_path(f2) as tmp:
            fig.savefig(tmp, dpi=90, format="png")
        plt.close(fig)
        files.append(str(f2))
    return files

"""``metro fit-plane CLOUD``: the datum plane of a laser-tracker cloud, robust, with its uncertainty."""

from __future__ import annotations

from typing import Optional

import typer

from ._common import echo_json, guarded


def _table(fit) -> str:
    """The readable report of a :class:`metrology.planefit.PlaneFit`."""
    import math

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


def register(app: typer.Typer) -> None:
    @app.command("fit-plane")
    @guarded
    def fit_plane(
        cloud: str = typer.Argument(..., help="Point cloud: .ply .pcd .e57 .xyz .xyzn .xyzrgb .pts .csv .txt (mm)."),
        threshold_mm: Optional[float] = typer.Option(
            None, "--threshold-mm", help="Inlier threshold on the distance to the plane, mm (default: 3 x robust sigma of the residuals)."
        ),
        seed: int = typer.Option(0, "--seed", help="Seed of the subsample and RANSAC (same seed, same bytes)."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON instead of a table."),
        out: Optional[str] = typer.Option(None, "--out", help="Write the plane JSON (other commands' --plane)."),
        plot: Optional[str] = typer.Option(None, "--plot", help="Write a residual map over the plate (.png/.pdf/.svg)."),
    ) -> None:
        """Fit the datum plane to a point cloud: RANSAC inliers, total-least-squares refit,
        uncertainty and form."""
        from metrology.jobs.fit_plane import fit_plane_file

        fit = fit_plane_file(cloud, threshold_mm=threshold_mm, seed=seed, out=out, plot=plot)
        if as_json:
            echo_json(fit.to_dict())
        else:
            typer.echo(_table(fit))

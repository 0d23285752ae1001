"""``metro fit-plane CLOUD``: the datum plane of a laser-tracker cloud, robust, with its uncertainty."""

from __future__ import annotations

from typing import Optional

import typer

from ._common import REPORT_HELP, echo_json, guarded, invocation


def register(app: typer.Typer) -> None:
    @app.command("fit-plane")
    @guarded
    def fit_plane(
        ctx: typer.Context,
        cloud: str = typer.Argument(..., help="Point cloud: .ply .pcd .e57 .xyz .xyzn .xyzrgb .pts .csv .txt (mm)."),
        threshold_mm: Optional[float] = typer.Option(
            None, "--threshold-mm", help="Inlier threshold on the distance to the plane, mm (default: 3 x robust sigma of the residuals)."
        ),
        seed: int = typer.Option(0, "--seed", help="Seed of the subsample and RANSAC (same seed, same bytes)."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON instead of a table."),
        out: Optional[str] = typer.Option(None, "--out", help="Write the plane JSON (other commands' --plane)."),
        plot: Optional[str] = typer.Option(None, "--plot", help="Write a residual map over the plate (.png/.pdf/.svg)."),
        units: Optional[str] = typer.Option(None, "--units", help="Unit of the cloud's numbers: mm (default), m or in."),
        report: Optional[str] = typer.Option(None, "--report", help=REPORT_HELP),
    ) -> None:
        """Fit the datum plane to a point cloud: RANSAC inliers, total-least-squares refit,
        uncertainty and form."""
        from metrology.jobs.fit_plane import fit_plane_file
        from metrology.report.datum import format_plane_fit

        if units is not None and units not in ("mm", "m", "in"):
            raise ValueError(f"--units {units!r}: expected mm, m or in")
        fit = fit_plane_file(cloud, threshold_mm=threshold_mm, seed=seed, out=out, plot=plot, units=units, report=report,
                             command=invocation(ctx),
                             warn=lambda message: typer.echo(f"warning: {message}", err=True))
        if as_json:
            echo_json(fit.to_dict())
        else:
            typer.echo(format_plane_fit(fit))

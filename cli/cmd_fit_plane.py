"""``metro fit-plane CLOUD``: the datum plane of a laser-tracker cloud, robust, with its uncertainty."""

from __future__ import annotations

from typing import Optional

import typer

from ._common import (JSON_HELP, REPORT_HELP, echo, echo_json, fail, finish, guarded, invocation, progress_bar, reported,
                      warn, with_verdict)

CLOUD_FORMATS = ("ply", "pcd", "e57", "xyz", "xyzn", "xyzrgb", "pts", "csv", "txt")


def register(app: typer.Typer) -> None:
    @app.command("fit-plane")
    @guarded
    def fit_plane(
        ctx: typer.Context,
        cloud: str = typer.Argument(..., help="Point cloud: .ply .pcd .e57 .xyz .xyzn .xyzrgb .pts .csv .txt (mm); "
                                    "'-' for stdin."),
        threshold_mm: Optional[float] = typer.Option(
            None, "--threshold-mm", help="Inlier threshold on the distance to the plane, mm (default: 3 x robust sigma of the residuals)."
        ),
        seed: int = typer.Option(0, "--seed", help="Seed of the subsample and RANSAC (same seed, same bytes)."),
        as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
        out: Optional[str] = typer.Option(None, "--out", help="Write the plane JSON (other commands' --plane)."),
        plot: Optional[str] = typer.Option(None, "--plot", help="Write a residual map over the plate (.png/.pdf/.svg)."),
        units: Optional[str] = typer.Option(None, "--units", help="Unit of the cloud's numbers: mm (default), m or in."),
        fmt: Optional[str] = typer.Option(None, "--format", help="Format of a cloud on stdin (CLOUD '-'): "
                                          f"{', '.join(CLOUD_FORMATS)}; PLY and PCD are also known by their header."),
        report: Optional[str] = typer.Option(None, "--report", help=REPORT_HELP),
        flatness_mm: Optional[float] = typer.Option(None, "--flatness-mm", help="Flatness tolerance of the datum, mm: "
                                                    "P-V of the inliers above it fails (exit 1). Default: none judged."),
        inliers: Optional[str] = typer.Option(None, "--inliers", help="Write the inlier points here (.ply, mm)."),
        outliers: Optional[str] = typer.Option(None, "--outliers", help="Write the outlier points here (.ply, mm)."),
        residuals: Optional[str] = typer.Option(None, "--residuals", help="Write each point's signed distance to the "
                                                "plane and whether it is an inlier (.csv, or .parquet with pyarrow)."),
    ) -> None:
        """Fit the datum plane to a point cloud: RANSAC inliers, total-least-squares refit,
        uncertainty and form."""
        from metrology.jobs.fit_plane import fit_plane_file
        from metrology.report.datum import format_plane_fit
        from metrology.report.verdicts import plane_verdict, verdict_text

        from ._stdin import format_suffix, stdin_files

        if units is not None and units not in ("mm", "m", "in"):
            raise ValueError(f"--units {units!r}: expected mm, m or in")
        if flatness_mm is not None and not flatness_mm > 0:
            fail(f"--flatness-mm {flatness_mm:g}: expected a positive number")
        if fmt is not None and (cloud != "-" or fmt.lower() not in CLOUD_FORMATS):
            fail(f"--format {fmt}: " + ("only for a cloud on stdin (CLOUD '-'); a file's suffix names its format"
                                        if cloud != "-" else f"expected one of {', '.join(CLOUD_FORMATS)}"))
        suffix = format_suffix("CLOUD", fmt, {"." + f for f in CLOUD_FORMATS}, "cloud")
        with stdin_files(("CLOUD", cloud, suffix)) as (path,), progress_bar("fit-plane") as progress:
            fit = fit_plane_file(path, threshold_mm=threshold_mm, seed=seed, out=out, plot=plot, units=units, warn=warn,
                                 report=report, command=invocation(ctx), flatness_mm=flatness_mm, inliers=inliers,
                                 outliers=outliers, residuals=residuals,
                                 progress=progress)
        verdict = plane_verdict(fit, flatness_mm)
        if as_json:
            echo_json(with_verdict(fit.to_dict(), verdict), "plane")
        else:
            echo(format_plane_fit(fit) + "\n" + verdict_text(verdict))
        reported(report)
        finish(verdict)

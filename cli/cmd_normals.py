"""``metro normals``: micro-plane against micro-sphere normals on a CAD panel (issue 5)."""

from __future__ import annotations

from pathlib import Path

import typer

from ._common import (JSON_HELP, REPORT_HELP, echo, echo_json, fail, finish, guarded, invocation, progress_bar, reported,
                      warn, with_verdict)
from ._stdin import MESH_FORMATS

STDIN = " ('-' for stdin)"


def register(app: typer.Typer) -> None:
    @app.command("normals")
    @guarded
    def normals(
        ctx: typer.Context,
        panel: Path = typer.Argument(..., help="Panel mesh in mm (STL, OBJ, PLY, GLB/GLTF; STEP with cascadio)" + STDIN),
        layout: Path = typer.Option(..., "--layout", help="Sensor layout TOML (nominal or calibrated)" + STDIN),
        points: Path = typer.Option(None, "--points", help="CSV of drilling points x,y,z,i,j,k or x,y,z (mm; approach = "
                                    "feed)" + STDIN),
        grid: float = typer.Option(None, "--grid", help="Regular grid of drilling points, spacing in mm."),
        tilt_deg: float = typer.Option(1.0, "--tilt-deg", help="Initial attitude error of the tool axis (random azimuth)."),
        standoff_mm: float = typer.Option(None, "--standoff-mm", help="Sensor-zero plane to drilling point along the tool axis; default from the layout."),
        noise_mm: float = typer.Option(None, "--noise-mm", help="Reading noise, 1 sigma; default the layout's noise_mm (0 where absent)."),
        seed: int = typer.Option(0, "--seed", help="Random seed (same seed, same output)."),
        tolerance_deg: float = typer.Option(0.5, "--tolerance-deg", help="Attitude-loop tolerance."),
        engine: str = typer.Option("auto", "--engine", help="Ray engine: auto, trimesh, embree, open3d."),
        out: Path = typer.Option(None, "--out", help="Per-point results, .csv or .json."),
        as_json: bool = typer.Option(False, "--json", help=JSON_HELP),
        plot: Path = typer.Option(None, "--plot", help="PNG map of the errors over the panel."),
        report: Path = typer.Option(None, "--report", help=REPORT_HELP),
        true_layout: Path = typer.Option(None, "--true-layout", help="Simulate the head as this layout (default: --layout)"
                                         + STDIN),
        motion_repeat_deg: float = typer.Option(0.02, "--motion-repeat-deg", help="Robot: random rotation error per adjustment, 1 sigma per axis."),
        motion_scale: float = typer.Option(0.03, "--motion-scale", help="Robot: relative error of a commanded rotation, 1 sigma."),
        motion_position_mm: float = typer.Option(0.05, "--motion-position-mm", help="Robot: TCP position error per adjustment, 1 sigma per axis."),
        sphere_prior_radius_mm: float = typer.Option(100.0, "--sphere-prior-radius-mm", help="Micro-sphere curvature prior (1 sigma = 1/this); inf = exact sphere."),
        no_loop: bool = typer.Option(False, "--no-loop", help="Measure once; skip the attitude loop."),
        fmt: str = typer.Option(None, "--format", help=f"Format of a panel on stdin (PANEL '-'): {', '.join(MESH_FORMATS)}; "
                                "ASCII STL, PLY and GLB are also known by their header."),
        units: str = typer.Option(None, "--units", help="Unit of the panel file's coordinates: mm, cm, m or in (overrides what the file declares; STL/OBJ/PLY declare none: mm)."),
        beams: str = typer.Option("facets", "--beams", help="What the simulated beams hit: facets (the mesh as it is) or "
                                  "smooth (the surface the mesh tessellates: Phong on the crease-aware normals)."),
        footprint_mm: float = typer.Option(None, "--footprint-mm", help="Radius of the head's footprint (pressure foot); default the spots' radius."),
    ) -> None:
        """Micro-plane against micro-sphere normals at drilling points on a panel, and the attitude loop."""
        from metrology.jobs.normals import normals_job
        from metrology.report.normals import summary_text
        from metrology.report.verdicts import normals_verdict, verdict_text

        from ._stdin import format_suffix, stdin_files

        if fmt is not None and (str(panel) != "-" or fmt.lower() not in MESH_FORMATS):
            fail(f"--format {fmt}: " + ("only for a panel on stdin (PANEL '-'); a file's suffix names its format"
                                        if str(panel) != "-" else f"expected one of {', '.join(MESH_FORMATS)}"))
        mesh_suffix = format_suffix("PANEL", fmt, {"." + f for f in MESH_FORMATS}, "panel")
        with stdin_files(("PANEL", panel, mesh_suffix), ("--layout", layout, ".toml"), ("--points", points, ".csv"),
                         ("--true-layout", true_layout, ".toml")) as (panel, layout, points, true_layout), \
                progress_bar("normals") as progress:
            summary = normals_job(
                panel, layout, points_path=points, grid_mm=grid, tilt_deg=tilt_deg, standoff_mm=standoff_mm,
                noise_mm=noise_mm, seed=seed, tolerance_deg=tolerance_deg, engine=engine, out_path=out, plot_path=plot,
                true_layout_path=true_layout, motion_repeat_deg=motion_repeat_deg, motion_scale=motion_scale,
                motion_position_mm=motion_position_mm, prior_radius_mm=sphere_prior_radius_mm, loop=not no_loop,
                progress=progress, report=report, command=invocation(ctx), units=units,
                footprint_mm=footprint_mm, on_warning=warn, beams=beams,
            )
        verdict = normals_verdict(summary, tolerance_deg)
        if as_json:
            echo_json(with_verdict(summary, verdict), "normals")
        else:
            echo(summary_text(summary) + "\n" + verdict_text(verdict))
        reported(report)
        finish(verdict)

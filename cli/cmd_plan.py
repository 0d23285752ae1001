"""``metro plan``: the calibration poses to take, chosen before any data exist."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._common import JSON_HELP, echo, echo_json, fail, guarded, output_path, parse_range, progress_bar, with_verdict
from ._stdin import plane_suffix, stdin_files

STDIN = " ('-' for stdin)"


def register(app: typer.Typer) -> None:
    @app.command("plan")
    @guarded
    def plan(
        layout: Path = typer.Option(..., "--layout", help="Nominal sensor layout TOML" + STDIN),
        plane: Path = typer.Option(..., "--plane", help="Datum: a tracker cloud (its extent is used), or a fit-plane JSON" + STDIN),
        poses: int = typer.Option(..., "--poses", help="Number of poses to plan (at least 5)."),
        tilt_max_deg: float = typer.Option(10.0, "--tilt-max-deg", help="Largest tilt of the tool axis from the datum normal, deg."),
        standoff_mm: Optional[str] = typer.Option(None, "--standoff-mm", help="MIN,MAX mean reading on a plane normal to the tool axis, mm (default: the range less the margin)."),
        working_standoff_mm: Optional[float] = typer.Option(None, "--working-standoff-mm", help="Where the normal's sigma is predicted, mm (default: mid stand-off)."),
        noise_mm: Optional[float] = typer.Option(None, "--noise-mm", help="Reading noise, 1 sigma, mm (default: the layout's noise_mm)."),
        range_mm: Optional[str] = typer.Option(None, "--range-mm", help="MIN,MAX valid readings, mm (default: the layout's range_mm)."),
        extent: Optional[Path] = typer.Option(None, "--extent", help="Datum cloud whose extent the spots must stay on (default: --plane when it is a cloud)."),
        extent_radius_mm: Optional[float] = typer.Option(None, "--extent-radius-mm", help="Without a cloud: a disc of this radius around the plane JSON's centroid, mm."),
        margin_mm: float = typer.Option(2.0, "--margin-mm", help="Kept from each end of the sensor range, mm."),
        spot_margin_mm: float = typer.Option(5.0, "--spot-margin-mm", help="Kept from the edge of the datum's extent, mm."),
        robot_error_mm: float = typer.Option(1.0, "--robot-error-mm", help="How far the robot may land from a planned position, mm."),
        robot_error_deg: float = typer.Option(0.1, "--robot-error-deg", help="How far it may turn from a planned attitude, deg (also the tilt margin)."),
        tool_side: str = typer.Option("normal", "--tool-side", help="The tool is on the side the plane's normal points to ('normal') or the other ('against')."),
        candidates: int = typer.Option(5000, "--candidates", help="Random poses drawn to choose from."),
        seed: int = typer.Option(0, "--seed", help="Seed of the candidates and the robot-error trials."),
        out: Optional[str] = typer.Option(None, "--out", help="Write the poses CSV (export contract, empty d_ columns) here."),
        plot: Optional[str] = typer.Option(None, "--plot", help="Write the sigma-against-k figure here (PNG, PDF, SVG)."),
        separate: Optional[str] = typer.Option(None, "--separate", help="Also tell these causes from the sensor parameters (comma-separated): incidence (with the gain and curve), scale, nonlinearity."),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP + " The plan and its predictions."),
    ) -> None:
        """Plan the calibration poses: D-optimal for the identifiable parameters, feasible, ordered."""
        for value, name in ((margin_mm, "--margin-mm"), (spot_margin_mm, "--spot-margin-mm"),
                            (robot_error_mm, "--robot-error-mm"), (robot_error_deg, "--robot-error-deg")):
            if not value >= 0:
                fail(f"{name} {value:g}: expected a number >= 0")
        if noise_mm is not None and not noise_mm > 0:
            fail(f"--noise-mm {noise_mm:g}: expected a positive number")
        out, plot = output_path(out, "--out"), output_path(plot, "--plot")
        from metrology.jobs.plan import plan_files
        from metrology.report.plan import plan_text

        with stdin_files(("--layout", layout, ".toml"), ("--plane", plane, plane_suffix),
                         ("--extent", extent, plane_suffix)) as (layout, plane, extent), progress_bar("plan") as progress:
            progress(0, 1, f"choosing {poses} poses from {candidates} candidates")
            result = plan_files(layout, plane, poses, tilt_max_deg, parse_range(standoff_mm, "--standoff-mm"), working_standoff_mm,
                                noise_mm, parse_range(range_mm, "--range-mm"), extent, extent_radius_mm, margin_mm,
                                spot_margin_mm, robot_error_mm, robot_error_deg, tool_side, candidates, seed, out, plot,
                                tuple(c.strip() for c in separate.split(",")) if separate else ())
        if json_out:
            from metrology.report.verdicts import NO_VERDICT

            echo_json(with_verdict({**result.to_dict(), "out": None if out is None else str(out)}, NO_VERDICT), "plan")
        else:
            echo(plan_text(result, out))

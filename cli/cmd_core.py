"""Core commands: ``reproduce`` (paper section 5) and ``demo`` (the bundled walk-through)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._common import JSON_HELP, echo_json, fail, guarded, invocation, progress_bar


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo(
        ctx: typer.Context,
        fixtures: Optional[Path] = typer.Option(None, help="Data to run on (default: the data shipped with metro)."),
        out: Optional[Path] = typer.Option(None, help="Folder for the outputs (default: a new folder metro-demo "
                                           "in the current directory; metro-demo-2, ... if that one is taken)."),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP + " Each step's command and its own JSON."),
        report: Optional[Path] = typer.Option(None, "--report", help="One HTML report of every step (.html); each "
                                              "step's own report is written into the output folder too."),
    ) -> None:
        """Run the main job on the bundled data: fit-plane -> calibrate -> validate -> diagnose -> normals."""
        import contextlib
        import io
        import json
        import shlex

        from typer.main import get_command

        from metrology.io.data import DATA_DIR
        from metrology.jobs.demo import new_output_dir, run_demo

        fixtures = DATA_DIR if fixtures is None else fixtures
        out = new_output_dir() if out is None else out
        command = get_command(app)
        steps = []

        def announce(title, args):
            steps.append({"title": title, "command": "metro " + shlex.join(args)})
            if not json_out:
                typer.secho(f"\n== {title}\n$ metro {' '.join(args)}", bold=True)

        def run_step(args):
            if not json_out:
                return command.main(args, prog_name="metro", standalone_mode=False)
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf):
                rc = command.main([*args, "--json"], prog_name="metro", standalone_mode=False)
            steps[-1]["result"] = None if rc else json.loads(buf.getvalue())
            return rc

        try:
            with progress_bar("demo") as progress:
                rc = run_demo(fixtures, out, run_step, announce, report=report, command=invocation(ctx),
                              progress=progress)
        except ValueError as exc:
            fail(str(exc))
        if rc:  # a failing step has printed its one-line error
            raise typer.Exit(rc)
        if json_out:
            echo_json({"out": str(out), "fixtures": str(fixtures), "steps": steps}, "demo")
        else:
            typer.echo(f"\ndemo outputs in {out}/")

    @app.command("version")
    def version(json_out: bool = typer.Option(False, "--json", help=JSON_HELP)) -> None:
        """Print metro's version."""
        from metrology import __version__

        if json_out:
            echo_json({"version": __version__}, "version")
        else:
            typer.echo(__version__)

    @app.command("reproduce")
    @guarded
    def reproduce(
        layout: str = typer.Option("simulation", help="simulation (Tables 1-2) or experiment (Tables 5-6, its Q and R)."),
        trials: int = typer.Option(1, min=1, help="Repeat with N seeds; report mean and spread."),
        seed: int = typer.Option(2018, help="Seed of the first trial's random stream."),
        poses: int = typer.Option(100, min=6, help="Calibration poses."),
        noise_mm: float = typer.Option(0.01, min=0.0, help="Reading noise, 1 sigma, mm."),
        tilt_deg: float = typer.Option(5.0, min=0.0, max=60.0, help="Largest tilt of the tool axis from the datum normal, deg."),
        standoff_mm: tuple[float, float] = typer.Option((40.0, 60.0), help="Range of the mean reading (stand-off), mm."),
        spread_mm: float = typer.Option(200.0, min=0.0, help="Side of the square the drilling points spread over, mm."),
        figures: Optional[Path] = typer.Option(Path("metro-reproduce"), help="Directory for Figures 7 and 8 (PNG); '-' for none."),
        json_out: bool = typer.Option(False, "--json", help=JSON_HELP),
    ) -> None:
        """Reproduce the paper's simulation (section 5): Tables 1, 3, 4 and Figures 7, 8."""
        import numpy as np

        from metrology.jobs.reproduce import reproduce as run_reproduce
        from metrology.report.reproduce import format_reproduce
        from metrology.sim.reproduce import ReproduceConfig
        from metrology.sim.simulation import PoseSpec

        if standoff_mm[0] >= standoff_mm[1] or standoff_mm[0] <= 0:
            fail(f"--standoff-mm {standoff_mm[0]:g} {standoff_mm[1]:g}: expected 0 < min < max")
        fig_dir = None if figures is None or str(figures) == "-" else figures
        cfg = ReproduceConfig(layout=layout, n_poses=poses, noise_mm=noise_mm,
                              poses=PoseSpec(tuple(standoff_mm), float(np.deg2rad(tilt_deg)), spread_mm))
        with progress_bar("reproduce") as progress:
            summary = run_reproduce(cfg, seed, trials, fig_dir, progress=progress)
        if json_out:
            echo_json(summary, "reproduce")
        else:
            typer.echo(format_reproduce(summary))
            if fig_dir is not None:
                typer.echo(f"figures: {', '.join(summary['figures'])}")

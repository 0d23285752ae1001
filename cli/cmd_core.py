"""Core commands: ``reproduce`` (paper section 5) and ``demo`` (the bundled walk-through)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ._common import (JSON_HELP, echo_json, fail, finish, guarded, invocation, parse_range, progress_bar, reported,
                      with_verdict)


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
        """Run the main job on the bundled data: fit-plane -> calibrate -> validate -> diagnose -> calibrate -> normals -> simulate-log -> measure."""
        import contextlib
        import io
        import json
        import shlex

        from typer.main import get_command

        from metrology.core.verdict import EXIT_FAILED
        from metrology.io.data import DATA_DIR
        from metrology.jobs.demo import new_output_dir, run_demo
        from metrology.report.verdicts import steps_verdict, verdict_text

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
                rc = command.main(args, prog_name="metro", standalone_mode=False) or 0
            else:
                buf = io.StringIO()
                with contextlib.redirect_stdout(buf):
                    rc = command.main([*args, "--json"], prog_name="metro", standalone_mode=False) or 0
                steps[-1]["result"] = json.loads(buf.getvalue()) if rc in (0, EXIT_FAILED) else None
            steps[-1]["exit_code"] = rc
            return rc

        try:
            with progress_bar("demo") as progress:
                rc = run_demo(fixtures, out, run_step, announce, report=report, command=invocation(ctx),
                              progress=progress)
        except ValueError as exc:
            fail(str(exc))
        if rc and rc != EXIT_FAILED:  # bad input: the failing step has printed its one-line error
            raise typer.Exit(rc)
        verdict = steps_verdict((s["command"].split()[1], s["exit_code"]) for s in steps)
        if json_out:
            echo_json(with_verdict({"out": str(out), "fixtures": str(fixtures), "steps": steps}, verdict), "demo")
        else:
            typer.echo(f"\ndemo outputs in {out}/\n" + verdict_text(verdict))
        reported(report)
        finish(verdict)

    @app.command("version")
    def version(json_out: bool = typer.Option(False, "--json", help=JSON_HELP)) -> None:
        """Print metro's version."""
        from metrology import __version__

        if json_out:
            from metrology.report.verdicts import NO_VERDICT

            echo_json(with_verdict({"version": __version__}, NO_VERDICT), "version")
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
        standoff_mm: str = typer.Option("40,60", help="MIN,MAX of the mean reading (stand-off), mm."),
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

        standoff_mm = parse_range(standoff_mm, "--standoff-mm", positive=True)
        fig_dir = None if figures is None or str(figures) == "-" else figures
        cfg = ReproduceConfig(layout=layout, n_poses=poses, noise_mm=noise_mm,
                              poses=PoseSpec(tuple(standoff_mm), float(np.deg2rad(tilt_deg)), spread_mm))
        with progress_bar("reproduce") as progress:
            summary = run_reproduce(cfg, seed, trials, fig_dir, progress=progress)
        if json_out:
            from metrology.report.verdicts import NO_VERDICT

            echo_json(with_verdict(summary, NO_VERDICT), "reproduce")
        else:
            typer.echo(format_reproduce(summary))
            if fig_dir is not None:
                typer.echo(f"figures: {', '.join(summary['figures'])}")
            from metrology.report.verdicts import NO_VERDICT_LINE

            typer.echo(NO_VERDICT_LINE)

"""The ``metro`` typer app. Each command lives in its own module and registers itself.

Only typer and the standard library are imported here and in the command modules' top
level, so ``metro --help`` stays instant; the library is imported inside each command.
"""

from __future__ import annotations

import typer

from ._help import MetroGroup, use_metro_command

app = typer.Typer(
    name="metro",
    help="Metrology for robotic drilling: datum planes, normal-sensor calibration, normals.",
    cls=MetroGroup,
    add_completion=True,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            v = version("metro")
        except PackageNotFoundError:  # run from a source tree that is not installed
            v = "unknown (not installed)"
        typer.echo(f"metro {v}")
        raise typer.Exit()


@app.callback(invoke_without_command=True)
def _root(
    ctx: typer.Context,
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print metro's version and exit."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No warnings, no progress bars (errors still print)."),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Note on stderr what each step did and its time."),
) -> None:
    """Metrology for robotic drilling: datum planes, normal-sensor calibration, normals."""
    import warnings

    from ._common import begin_run, note, show_warning

    ctx.call_on_close(begin_run(quiet, verbose))
    ctx.with_resource(warnings.catch_warnings())  # restored when the run ends
    warnings.showwarning = show_warning  # a library warning: one "warning:" line on stderr
    if quiet:
        warnings.simplefilter("ignore")
    if ctx.invoked_subcommand is not None:
        note(f"metro {ctx.invoked_subcommand}")
        ctx.call_on_close(lambda: note(f"metro {ctx.invoked_subcommand}: done"))
    if ctx.invoked_subcommand is None:  # `metro` alone: the help, and success
        typer.echo(ctx.get_help())
        raise typer.Exit(0)

from . import (cmd_calibrate, cmd_core, cmd_diagnose, cmd_fit_plane, cmd_measure, cmd_normals,  # noqa: E402
               cmd_plan, cmd_simulate_log)

for _module in (cmd_fit_plane, cmd_plan, cmd_calibrate, cmd_normals, cmd_diagnose, cmd_measure, cmd_simulate_log,
                cmd_core):
    _module.register(app)
use_metro_command(app)


def main() -> None:
    app()


if __name__ == "__main__":
    main()

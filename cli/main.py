"""The ``metro`` typer app. Each command lives in its own module and registers itself.

Only typer and the standard library are imported here and in the command modules' top
level, so ``metro --help`` stays instant; the library is imported inside each command.
"""

from __future__ import annotations

import typer

app = typer.Typer(
    name="metro",
    help="Metrology for robotic drilling: datum planes, normal-sensor calibration, normals.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

from . import cmd_calibrate, cmd_core, cmd_diagnose, cmd_fit_plane, cmd_normals  # noqa: E402

for _module in (cmd_fit_plane, cmd_calibrate, cmd_normals, cmd_diagnose, cmd_core):
    _module.register(app)


def main() -> None:
    app()


if __name__ == "__main__":
    main()

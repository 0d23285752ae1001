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

from . import cmd_core  # noqa: E402

cmd_core.register(app)
for _name in ("cmd_fit_plane", "cmd_calibrate", "cmd_normals", "cmd_diagnose"):
    try:
        _mod = __import__(f"cli.{_name}", fromlist=["register"])
    except ModuleNotFoundError as _exc:  # a command module not yet written
        if _exc.name != f"cli.{_name}":
            raise
        continue
    _mod.register(app)


def main() -> None:
    app()


if __name__ == "__main__":
    main()

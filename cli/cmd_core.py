"""Core commands: reproduce (paper section 5) and demo."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    @app.command("version")
    def version() -> None:
        """Print metro's version."""
        from metrology import __version__

        typer.echo(__version__)

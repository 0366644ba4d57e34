"""``hil version``: the package version (also stamped into every run's provenance)."""

from __future__ import annotations

import typer

from hil.provenance import package_version


def register(app: typer.Typer) -> None:
    @app.command("version")
    def version() -> None:
        """Print the package version."""
        typer.echo(package_version())

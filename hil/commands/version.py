"""``hil version``: the package version (also stamped into every run's provenance)."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _dist_version

import typer


def package_version() -> str:
    try:
        return _dist_version("hil-smc-bench")
    except PackageNotFoundError:
        return "0+unknown"


def register(app: typer.Typer) -> None:
    @app.command("version")
    def version() -> None:
        """Print the package version."""
        typer.echo(package_version())

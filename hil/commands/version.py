"""``hil version``: the package version, also stamped into every run's provenance."""

from __future__ import annotations

import typer

from hil.commands import app
from hil.provenance import package_version


@app.command("version")
def version() -> None:
    """Print the package version."""
    typer.echo(package_version())

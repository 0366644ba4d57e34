"""What ships with the package: ``hil scenarios`` (the bundled scenarios, one line each)."""

from __future__ import annotations

from typing import Annotated

import typer

from hil.bundled import bundled_dir, bundled_names, bundled_path, description
from hil.commands import app


@app.command("scenarios")
def scenarios(
    path: Annotated[
        str | None,
        typer.Option(metavar="NAME", help="Print the file of the bundled scenario NAME."),
    ] = None,
) -> None:
    """List the scenarios bundled with the package (the paper's Section 4 set-ups), one line
    each: its name and the first sentence of the comment that opens the file.

    Every command that takes a SCENARIO (hil sim, hil run, hil sweep, hil certify, hil
    controller, hil emulator) accepts either a path to a TOML file or one of these names, with
    or without .toml: `hil sim paper_tracking --out DIR`. A file that exists wins over a
    bundled name. --path prints where a bundled scenario's file is, to copy it as the start of
    your own: `cp $(hil scenarios --path paper_tracking) mine.toml`."""
    if path is not None:
        typer.echo(str(bundled_path(path)))
        return
    names = bundled_names()
    width = max((len(n) for n in names), default=0)
    for name in names:
        typer.echo(f"{name:<{width}}  {description(bundled_dir() / f'{name}.toml')}")

"""Your own control law on the command line: ``--law module:Class``, the same option and help on
``hil run``, ``sim`` and ``sweep`` (what it does: :func:`hil.law.option.with_law`), and
``hil new-law NAME``, a working law of your own and its test, written into your folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hil.commands import app

LAW_HELP = (
    "Control law instead of the scenario's: unified, unified_boundary, jiang1997, jiang2001 or "
    "your own 'module:Class' (a module next to the scenario or in the working directory is "
    "found without PYTHONPATH; hil new-law writes one). The scenario's [controller] "
    "parameters are kept only when they name the same law; otherwise the law's defaults."
)
LawOpt = Annotated[str | None, typer.Option(help=LAW_HELP)]


@app.command("new-law")
def new_law(
    name: Annotated[str, typer.Argument(help="Module name of the law, e.g. my_law.")],
    folder: Annotated[
        Path, typer.Option("--dir", help="Folder to write into (default: this one).")
    ] = Path("."),
    force: Annotated[bool, typer.Option(help="Overwrite files that exist.")] = False,
) -> None:
    """Write NAME.py (a tracking law that runs on floats and numpy arrays, within the
    limits (2)) and test_NAME.py (its tests) into the folder; docs/own-controller.md
    walks through them. The bench then finds the law without PYTHONPATH: hil sim
    paper_tracking --law NAME:Class (Class is NAME in CamelCase)."""
    from hil.law.template import check_name, class_name, write_law
    from hil.options import out_dir

    out_dir("--dir", folder)
    check_name(name, folder)
    written = write_law(name, folder, force)
    law = f"{name}:{class_name(name)}"
    for path in written:
        typer.echo(f"wrote {path}")
    # Runs right after the README's install: pytest is a test tool, not one of hil's own.
    typer.echo(f"test it:  python {written[1]}   (with pytest: python -m pytest {written[1]})")
    typer.echo(f"run it:   hil sim paper_tracking --law {law} --out runs/{name}")
    typer.echo(f"sweep it: hil sweep paper_tracking --law {law} --out runs/{name}-sweep")

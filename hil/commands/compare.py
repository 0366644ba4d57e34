"""``hil compare DIR_A DIR_B``: two run or simulation folders side by side."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from hil.commands import ForceOpt, app


@app.command("compare")
def compare(
    dir_a: Annotated[Path, typer.Argument(help="First run or simulation folder (A).")],
    dir_b: Annotated[Path, typer.Argument(help="Second folder (B).")],
    out: Annotated[
        Path | None, typer.Option(help="Where to write (default: a new folder under runs/).")
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Overlaid trajectories, v, ω, τ1, τ2, position error and (runs) latency CDFs of two
    folders (the Zenoh path against the CAN path, two rates, a run against its
    simulation) and a table of summary, sampling-effect and measured timing figures
    (hil.measure: timing, messages, certificate) with their differences (B - A):
    compare.html, compare.md, compare.json, PNG + CSV per figure. Exit 0, or 2 when a
    folder is not a run."""
    from hil.analysis.report.compare import build_compare
    from hil.folder import claim, load_folder

    claim.check("--out", out, force, default="runs")
    a, b = load_folder(dir_a), load_folder(dir_b)
    target = claim.take(out or Path("runs") / time.strftime("compare-%Y%m%d-%H%M%S"), "compare")
    build_compare(a, b, target)
    typer.echo(f"compare: {target / 'compare.html'}")

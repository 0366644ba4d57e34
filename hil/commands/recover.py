"""``hil recover DIR``: make a killed run's folder whole (see hil.bench.repair)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from hil.commands import app


@app.command("recover")
def recover_cmd(
    run_dir: Annotated[Path, typer.Argument(help="A run folder whose hil run was killed.")],
) -> None:
    """Rewrite a truncated recording as a complete, indexed MCAP (the services' hop logs
    and the resolved scenario attached), restore into it every State the plant sent that
    the recorder had not written yet (from the plant's hop log, marked restored_from), and
    rebuild trace.csv and summary.json from the hop logs. Nothing to do for a whole folder.
    `hil report` runs this by itself.

    Exit 2 when DIR is not a run folder or the run was killed before its first sample."""
    from hil.bench.repair import recover

    typer.echo(json.dumps(recover(run_dir), indent=2))

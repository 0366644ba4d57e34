"""``hil recover DIR``: make a killed run's folder whole: the bench's repair (the recording and
what the kill left, :mod:`hil.bench.repair`), then the analysis a finished run gets
(:func:`hil.analysis.analyze.analyze`: trace.csv, summary.json, trajectory.png)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from hil.commands import app

if TYPE_CHECKING:
    from hil.folder.records import Recovered


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
    typer.echo(json.dumps(recover(run_dir), indent=2))


def recover(run_dir: str | Path) -> Recovered:
    """Make a killed run's folder whole; returns what was done (also written to recovered.json
    when there was something to do). BadInputError when the folder is not a run folder (no
    settings, no hop logs) or holds no sample to rebuild from."""
    from hil.analysis.analyze import analyze, plot
    from hil.bench.repair import repair
    from hil.errors import BadInputError
    from hil.folder import layout
    from hil.folder.jsonio import write_json

    done, recorded = repair(run_dir)
    if not done["repaired"]:
        return done
    if recorded is not None:
        summary = analyze(recorded)
        if not summary.get("samples"):
            raise BadInputError(f"{recorded.run_dir}: the run was killed before its first sample")
        try:
            plot(recorded.run_dir)
        except Exception as exc:  # plots are a convenience; the figures are in summary.json
            done["plot_error"] = str(exc)
        done["samples"] = summary["samples"]
    write_json(Path(run_dir) / layout.RECOVERED, done)
    return done

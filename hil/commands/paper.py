"""``hil paper --out DIR``: the paper's Section 4 offline (Figures 2-20 and a table of measured
figures)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hil import interrupts
from hil.commands import ForceOpt, app
from hil.errors import NegativeVerdictError
from hil.ticker import start_line


@app.command("paper")
def paper(
    out: Annotated[
        Path | None, typer.Option(help="Folder to write (default: runs/paper-<time>).")
    ] = None,
    quick: Annotated[
        bool, typer.Option("--quick", help="Durations / 5 (smoke test; checks not judged).")
    ] = False,
    jobs: Annotated[int, typer.Option(min=1, help="Processes to run the simulations in.")] = 2,
    traces: Annotated[
        bool, typer.Option("--traces", help="Also write each run's full trace.csv.")
    ] = False,
    force: ForceOpt = False,
) -> None:
    """Reproduce the paper's tracking, stabilization, chattering reduction (19) and both
    comparisons ([7] on the tracking run, [19] on circle_then_stop) offline, at Ts = 1 ms
    with an RK4 plant at 0.1 ms. Writes PNG figures (data as CSV beside each), table.md and
    table.json. The scenarios are the bundled paper_* ones (hil scenarios). Each group of
    figures is written as soon as its runs are done; Ctrl-C keeps what was written (and a
    table of the runs done) and exits 130. Exit 1 when a check of the paper's claims
    fails. Takes about 2-4 minutes on 2 cores (--quick: under a minute)."""
    from hil.folder import claim, new_run_dir
    from hil.paper import run_paper

    claim.check("--out", out, force, default="runs")
    folder = claim.take(out or new_run_dir("runs", "paper"), "paper")
    how_long = "under a minute (--quick)" if quick else "about 2-4 minutes on 2 cores"
    what = f"the paper's Section 4 offline, {jobs} processes, a line as each run ends"
    start_line("paper", what, how_long, folder)
    table = run_paper(
        folder, quick=quick, jobs=jobs, traces=traces, log=lambda m: typer.echo(m, err=True)
    )
    typer.echo((folder / "table.md").read_text())
    typer.echo(f"wrote {folder}")
    if table.get("interrupted"):
        # hil.cli exits 130: the interrupt was recorded by hil.interrupts.
        done = len(list(folder.glob("fig*.png")))
        missing = ", ".join(table.get("runs_not_done") or []) or "none"
        interrupts.note(
            f"kept {done} figures and the table of the runs done in {folder}; runs not done: "
            f"{missing} (no claim about them, the paper's claims not checked)"
        )
        return
    failed = [c["check"] for c in table["checks"] if c["passed"] is False]
    if failed:
        raise NegativeVerdictError("; ".join(failed))

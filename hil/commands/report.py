"""``hil report DIR``: report.html / report.md / report.json of a run or simulation folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hil.errors import NegativeVerdictError


def register(app: typer.Typer) -> None:
    @app.command("report")
    def report(
        folder: Annotated[
            Path, typer.Argument(help="A run (hil run) or simulation (hil sim) folder.")
        ],
        out: Annotated[
            Path | None,
            typer.Option("--out", help="Where to write the report (default: the folder itself)."),
        ] = None,
        ideal: Annotated[
            bool,
            typer.Option(
                "--ideal/--no-ideal",
                help="Simulate the same scenario at a fine period (Ts/10) for the deviation "
                "from the ideal trajectory (needs the simulator).",
            ),
        ] = True,
        max_deadline_miss_ratio: Annotated[
            float,
            typer.Option(help="Deadline misses above this fraction of cycles: negative verdict."),
        ] = 0.01,
        max_lost_ratio: Annotated[
            float,
            typer.Option(help="Lost messages above this fraction of those sent: negative."),
        ] = 0.01,
    ) -> None:
        """Sampling-effect report: trajectory; v, ω, τ1, τ2 with their limits (red dashed);
        tracking error and deviation from the ideal trajectory; quasi-sliding bands and
        switching rates; latency histograms/CDFs per path and wake-up lateness (runs); and a
        verdict. Exit 0 all good, 1 negative verdict (limit broken, certificate not held or
        exceeded, too many deadline misses or lost messages), 2 not a run folder."""
        from hil.options import number, out_dir
        from hil.report.build import Thresholds, analyse, write_report
        from hil.report.folder import load_folder
        from hil.report.ideal import ideal_from_simulator

        number("--max-deadline-miss-ratio", max_deadline_miss_ratio, 0.0, 1.0)
        number("--max-lost-ratio", max_lost_ratio, 0.0, 1.0)
        out_dir("--out", out)
        loaded = load_folder(folder)
        rep = analyse(
            loaded,
            ideal=ideal_from_simulator if ideal else None,
            thresholds=Thresholds(max_deadline_miss_ratio, max_lost_ratio),
        )
        paths = write_report(rep, out or folder)
        typer.echo(f"report: {paths['html']}")
        v = rep.data["verdict"]
        if not v["ok"]:
            raise NegativeVerdictError("; ".join(v["reasons"]))
        typer.echo("verdict: PASS")

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
            bool | None,
            typer.Option(
                "--ideal/--no-ideal",
                help="Simulate the same scenario at a fine period (Ts/10) for the deviation "
                "from the ideal trajectory. Default: for the built-in laws only; a law of your "
                "own (module:Class) is run again, from its module, only with --ideal.",
                show_default=False,
            ),
        ] = None,
        max_deadline_miss_ratio: Annotated[
            float,
            typer.Option(help="Deadline misses above this fraction of cycles: negative verdict."),
        ] = 0.01,
        max_lost_ratio: Annotated[
            float,
            typer.Option(
                help="Lost messages (State and the applied command path) above this fraction "
                "of those sent: negative verdict."
            ),
        ] = 0.01,
        max_samples_without_command_ratio: Annotated[
            float,
            typer.Option(
                help="Plant samples whose command never landed above this fraction of the "
                "samples: negative verdict."
            ),
        ] = 0.01,
    ) -> None:
        """Sampling-effect report. First the answers: limits of (2) held and by what margin,
        the command age D against D* (the certificate), the stalls closest to D*, the share
        of samples without a command, the verdict. Then the details: trajectory (with the
        ideal one), v, ω, τ1, τ2 against (2), motor torques and drive states, tracking error,
        quasi-sliding bands, switching and saturation; for a run, latency histograms/CDFs,
        wake-up lateness, command age over time and every timing figure (summary.json, from
        hil.measure). Exit 0 all good, 1 negative verdict (limit broken, certificate not held
        or exceeded, too many deadline misses, samples without a command or lost messages),
        2 not a run folder."""
        from functools import partial

        from hil.folder import load_folder
        from hil.options import number, out_dir
        from hil.report.build import Thresholds, build_report, write_report
        from hil.report.ideal import ideal_from_simulator
        from hil.run.recover import is_run_folder, needs_recovery, recover

        number("--max-deadline-miss-ratio", max_deadline_miss_ratio, 0.0, 1.0)
        number("--max-lost-ratio", max_lost_ratio, 0.0, 1.0)
        number("--max-samples-without-command-ratio", max_samples_without_command_ratio, 0.0, 1.0)
        out_dir("--out", out)
        if is_run_folder(folder) and needs_recovery(folder):
            # A killed hil run: make the folder whole first (hil recover), then report.
            typer.echo(f"recovering {folder} first: {', '.join(needs_recovery(folder))}", err=True)
            recover(folder)
        loaded = load_folder(folder, lazy=True)
        rep = build_report(
            loaded,
            ideal=None if ideal is False else partial(ideal_from_simulator, user_law=bool(ideal)),
            thresholds=Thresholds(
                max_deadline_miss_ratio, max_lost_ratio, max_samples_without_command_ratio
            ),
        )
        paths = write_report(rep, out or folder)
        typer.echo(f"report: {paths['html']}")
        v = rep.data["verdict"]
        if not v["ok"]:
            raise NegativeVerdictError("; ".join(v["reasons"]))
        typer.echo("verdict: PASS")

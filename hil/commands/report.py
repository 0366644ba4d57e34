"""``hil report DIR``: report.html / report.md / report.json of a run or simulation folder."""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Annotated

import typer

from hil.commands import ForceOpt, app
from hil.errors import NegativeVerdictError
from hil.options import number


@app.command("report")
def report(
    folder: Annotated[Path, typer.Argument(help="A run (hil run) or simulation (hil sim) folder.")],
    out: Annotated[
        Path | None, typer.Option(help="Where to write the report (default: the folder itself).")
    ] = None,
    ideal: Annotated[
        bool | None,
        typer.Option(
            help="Simulate the same scenario at a fine period (Ts/10) for the deviation "
            "from the ideal trajectory. Default: for the built-in laws only; a law of your "
            "own (module:Class) is run again, from its module, only with --ideal.",
            show_default=False,
        ),
    ] = None,
    max_deadline_miss_ratio: Annotated[
        float,
        typer.Option(
            help="Missed slots above this fraction of the slots: FAIL (INCONCLUSIVE when only "
            "those inside the bench's stalls put them over)."
        ),
    ] = 0.01,
    max_lost_ratio: Annotated[
        float,
        typer.Option(
            help="Lost messages (State and the applied command path) above this fraction "
            "of those sent: FAIL."
        ),
    ] = 0.01,
    max_samples_without_command_ratio: Annotated[
        float,
        typer.Option(
            help="Samples without a command above this fraction of the samples the "
            "controller was meant to answer (one per control period): FAIL (INCONCLUSIVE when "
            "only those inside the bench's stalls put them over)."
        ),
    ] = 0.01,
    force: ForceOpt = False,
) -> None:
    """Sampling-effect report. First the answers: limits of (2) held and by what margin,
    the command age D against D* (the certificate), the stalls closest to D*, the share
    of samples without a command, the verdict. Then the details: trajectory (with the
    ideal one), v, ω, τ1, τ2 against (2), motor torques and drive states, tracking error,
    quasi-sliding bands, switching and saturation; for a run, latency histograms/CDFs,
    wake-up lateness, command age over time and every timing figure (summary.json, from
    hil.measure). Exit with the verdict's code: 0 PASS, 1 FAIL (limit broken, certificate
    not held or exceeded by the system's own timing, too many deadline misses, samples
    without a command or lost messages), 4 INCONCLUSIVE (the bench stalled, or the logs
    cannot relate a figure); 2 not a run folder (docs/reports.md, "Verdict and exit code")."""
    from hil.analysis.report.build import Thresholds, build_report, write_report
    from hil.analysis.report.ideal import ideal_from_simulator
    from hil.bench.repair import is_run_folder, needs_recovery
    from hil.commands.recover import recover
    from hil.folder import claim, load_folder

    number("--max-deadline-miss-ratio", max_deadline_miss_ratio, 0.0, 1.0)
    number("--max-lost-ratio", max_lost_ratio, 0.0, 1.0)
    number("--max-samples-without-command-ratio", max_samples_without_command_ratio, 0.0, 1.0)
    elsewhere = out is not None and out.resolve() != folder.resolve()
    claim.check("--out", out if elsewhere else None, force)  # else: its own folder, rewritten
    if is_run_folder(folder) and needs_recovery(folder):
        # A killed hil run: make the folder whole first (hil recover), then report.
        typer.echo(f"recovering {folder} first: {', '.join(needs_recovery(folder))}", err=True)
        recover(folder)
    _law_failed_at_once(folder)
    simulate = None if ideal is False else partial(ideal_from_simulator, user_law=bool(ideal))
    limits = Thresholds(max_deadline_miss_ratio, max_lost_ratio, max_samples_without_command_ratio)
    rep = build_report(load_folder(folder, lazy=True), ideal=simulate, thresholds=limits)
    paths = write_report(rep, claim.take(out, "report") if out and elsewhere else folder)
    typer.echo(f"report: {paths['html']}")
    v = rep.data["verdict"]
    if v["outcome"] != "PASS":  # FAIL exits 1, INCONCLUSIVE 4 (hil.verdict.EXIT_CODE)
        raise NegativeVerdictError("; ".join(v["reasons"]), v["outcome"])
    typer.echo("verdict: PASS")


def _law_failed_at_once(folder: Path) -> None:
    """A law that failed before its second sample leaves no trace to draw: its verdict is the
    fault (exit 1), said without a report."""
    from hil.folder import layout
    from hil.folder.jsonio import read_json_object
    from hil.verdict import law_ended

    path = folder / layout.SUMMARY
    if not path.is_file():
        return  # not a folder: load_folder says so
    summary = read_json_object(path)
    first = law_ended(summary)  # type: ignore[arg-type]
    samples = summary.get("samples")
    if first is not None and isinstance(samples, int) and samples < 2:
        raise NegativeVerdictError(
            f"{first} (no report: the trace ends at the fault, before its second sample)"
        )

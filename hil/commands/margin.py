"""``hil margin RUN_OR_SCENARIO``: the timing margin k* of a run or a scenario (docs/margin.md),
written to margin.json. Exit 1 when k* <= 1 (a limit breaks at the measured timing) or the law
failed in a loop (raised, returned the wrong type or a non-finite torque: margin.json holds the
record, no k*), 2 on bad input.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from hil import options
from hil.bundled import resolve_scenario
from hil.commands import ForceOpt, app
from hil.commands.new_law import LawOpt
from hil.errors import NegativeVerdictError
from hil.ticker import start_line


def _source(text: str, seeds: int, law: str | None = None):
    """(scenario, base timing, folder for margin.json or None); ``law``: --law instead of the
    scenario's."""
    from hil.analysis.margin.timing import from_run, from_scenario, run_scenario
    from hil.folder import has_hop_logs, load_folder
    from hil.law.option import with_law
    from hil.scenario import load_scenario

    path = Path(text)
    if path.is_dir():
        scenario = with_law(run_scenario(path), law)
        if has_hop_logs(path):
            return scenario, from_run(path, scenario), path
        # A simulation's folder: nothing was measured, so its scenario's [timing] is replayed
        # and margin.json goes beside the simulation's report.
        load_folder(path, lazy=True)  # BadInputError when it is no folder of hil sim either
        return scenario, from_scenario(scenario, seeds), path
    scenario = with_law(load_scenario(resolve_scenario(text)), law)
    return scenario, from_scenario(scenario, seeds), None


@app.command("margin")
def margin(
    source: Annotated[
        str,
        typer.Argument(
            help="A folder of hil run (its measured timing) or hil sim (its scenario's timing), "
            "a scenario TOML or a bundled scenario's name."
        ),
    ],
    seeds: Annotated[
        int, typer.Option(help="Loops per scale (timing draws, initial states).")
    ] = 32,
    worst_disturbance: Annotated[
        bool,
        typer.Option(
            "--worst-disturbance",
            help="Search the worst disturbance within s1, s2 at each scale (hil.adversary).",
        ),
    ] = False,
    error_bound: Annotated[
        float | None,
        typer.Option(
            help="Also break when the position error over the run's second half exceeds "
            "this many metres."
        ),
    ] = None,
    duration: Annotated[
        float | None, typer.Option(help="Simulated seconds per loop (default: the run's, <= 20 s).")
    ] = None,
    k_max: Annotated[
        float | None,
        typer.Option(
            help="The largest scale tried (default 64); when the limits still hold there, no k* "
            "is found below it (a loop at Ts = 1 ms that breaks near 100 ms of age needs ~100)."
        ),
    ] = None,
    out: Annotated[
        Path | None, typer.Option(help="Folder for margin.json when the source is a scenario.")
    ] = None,
    law: LawOpt = None,
    force: ForceOpt = False,
) -> None:
    """How much worse may the timing get before a limit of (2) breaks? (k*)"""
    from hil.analysis.margin import record
    from hil.analysis.margin.search import MarginOptions, find_margin
    from hil.folder import claim

    options.integer("--seeds", seeds, 1, 100_000)
    options.optional_number("--k-max", k_max, 1.0, 1e6)
    options.optional_number("--error-bound", error_bound, 0.0, 1e6, positive=True)
    options.optional_number("--duration", duration, 0.0, 3600.0, positive=True)
    scenario, base, folder = _source(source, seeds, law)
    if folder is None:  # margin.json into a folder of its own; else beside the run's report
        claim.check("--out", out, force)
    else:
        options.out_dir("--out", out)
    loop_s = duration if duration is not None else min(scenario.run.duration, 20.0)
    k_max = MarginOptions.k_max if k_max is None else k_max
    opts = MarginOptions(
        seeds=seeds, duration=loop_s, worst=worst_disturbance, error_bound=error_bound, k_max=k_max
    )

    def show(p) -> None:
        typer.echo(
            f"k = {p.k:.4g}: age {1e3 * p.age_s:.1f} ms, worst {p.limit} "
            f"{p.score:.3f} of its limit: {'BREAKS' if p.broke else 'holds'}"
        )

    target = _start(source, scenario, opts, folder or claim.take(_folder(out), "margin"))
    if folder is None:  # a scenario's margin: what ran, whole (a run's folder has its own)
        claim.write_scenario(target, scenario)
    result = find_margin(scenario, base, opts, show)
    written = record.write(target, result)
    for line in record.summary_lines(result):
        typer.echo(line)
    typer.echo(f"margin: {written}")
    fault = record.law_fault_sentence(result)
    if fault is not None:  # the law failed in a loop: a FAIL of the law, whatever k
        raise NegativeVerdictError(str(fault))
    if result.k_star is not None and result.k_star <= 1.0:
        raise NegativeVerdictError("a limit breaks at the measured timing (k* <= 1)")


def _say_once_if_one_robot_at_a_time(scenario) -> None:
    """A law that takes only floats runs one robot at a time on the batch path: said once,
    before the search (as hil sweep says it)."""
    from hil.law.batch import batch_note
    from hil.scenario import build_loop

    controller, reference, _ = build_loop(scenario)
    note = batch_note(controller, scenario, reference)
    if note:
        typer.echo(note, err=True)


def _folder(out: Path | None) -> Path:
    return out or Path("runs") / time.strftime("margin-%Y%m%d-%H%M%S")


def _start(source: str, scenario, opts, target: Path) -> Path:
    """The start line (hil.ticker) and, for a law on floats only, its note; ``target``."""
    law = scenario.controller.get("law", "unified")
    what = f"{source}, law {law}, k* searched up to {opts.k_max:g} ({opts.seeds} loops a scale)"
    long = f"{opts.duration:g} s simulated a loop, a line a scale"
    start_line("margin", what, long, target / "margin.json")
    _say_once_if_one_robot_at_a_time(scenario)
    return target

"""``hil margin RUN_OR_SCENARIO``: the timing margin k* of a run or a scenario.

Replays a run folder's measured timing (the applied path's landings, hil.measure) or a
scenario's [timing] (a bundled or TOML scenario, or the folder of a hil sim) in the batch
simulator with every command age scaled by k, over many seeds, and bisects for the smallest k
at which a limit of (2) (or ``--error-bound``) breaks. Writes margin.json into the run or
simulation folder (a scenario: into --out). Exit 0 when the margin is at least 1 (the limits
hold at the measured timing), 1 when k* < 1, 2 on bad input.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from hil.errors import NegativeVerdictError

SourceArg = Annotated[
    str,
    typer.Argument(
        help="A folder of hil run (its measured timing) or hil sim (its scenario's timing), "
        "a scenario TOML or a bundled scenario's name."
    ),
]
SeedsOpt = Annotated[int, typer.Option(help="Loops per scale (timing draws, initial states).")]
WorstOpt = Annotated[
    bool,
    typer.Option(
        "--worst-disturbance",
        help="Search the worst disturbance within s1, s2 at each scale (hil.adversary).",
    ),
]
ErrorOpt = Annotated[
    float | None,
    typer.Option(
        help="Also break when the position error over the run's second half exceeds "
        "this many metres."
    ),
]
DurationOpt = Annotated[
    float | None, typer.Option(help="Simulated seconds per loop (default: the run's, <= 20 s).")
]
KMaxOpt = Annotated[
    float | None,
    typer.Option(
        "--k-max",
        help="The largest scale tried (default 64); when the limits still hold there, no k* "
        "is found below it (a loop at Ts = 1 ms that breaks near 100 ms of age needs ~100).",
    ),
]
OutOpt = Annotated[
    Path | None, typer.Option(help="Folder for margin.json when the source is a scenario.")
]


def _source(text: str, seeds: int):
    """(scenario, base timing, folder for margin.json or None)."""
    from hil.bundled import resolve_scenario
    from hil.folder import has_hop_logs, load_folder
    from hil.margin.timing import from_run, from_scenario, run_scenario
    from hil.scenario import load_scenario

    path = Path(text)
    if path.is_dir():
        scenario = run_scenario(path)
        if has_hop_logs(path):
            return scenario, from_run(path, scenario), path
        # A simulation's folder: nothing was measured, so its scenario's [timing] is replayed
        # and margin.json goes beside the simulation's report.
        load_folder(path, lazy=True)  # BadInputError when it is no folder of hil sim either
        return scenario, from_scenario(scenario, seeds), path
    scenario = load_scenario(resolve_scenario(text))
    return scenario, from_scenario(scenario, seeds), None


def register(app: typer.Typer) -> None:
    @app.command("margin")
    def margin(
        source: SourceArg,
        seeds: SeedsOpt = 32,
        worst_disturbance: WorstOpt = False,
        error_bound: ErrorOpt = None,
        duration: DurationOpt = None,
        k_max: KMaxOpt = None,
        out: OutOpt = None,
    ) -> None:
        """How much worse may the timing get before a limit of (2) breaks? (k*)"""
        from hil import options
        from hil.margin import record
        from hil.margin.search import MarginOptions, find_margin

        options.integer("--seeds", seeds, 1, 100_000)
        if k_max is not None:
            options.number("--k-max", k_max, 1.0, 1e6)
        if error_bound is not None:
            options.number("--error-bound", error_bound, 0.0, 1e6, positive=True)
        if duration is not None:
            options.number("--duration", duration, 0.0, 3600.0, positive=True)
        options.out_dir("--out", out)
        scenario, base, folder = _source(source, seeds)
        loop_s = duration if duration is not None else min(scenario.run.duration, 20.0)
        opts = MarginOptions(
            seeds=seeds,
            duration=loop_s,
            worst=worst_disturbance,
            error_bound=error_bound,
            k_max=MarginOptions.k_max if k_max is None else k_max,
        )

        def show(p) -> None:
            state = "BREAKS" if p.broke else "holds"
            typer.echo(
                f"k = {p.k:.4g}: age {1e3 * p.age_s:.1f} ms, worst {p.limit} "
                f"{p.score:.3f} of its limit: {state}"
            )

        result = find_margin(scenario, base, opts, show)
        target = folder or out or Path("runs") / time.strftime("margin-%Y%m%d-%H%M%S")
        target.mkdir(parents=True, exist_ok=True)
        written = record.write(target, result)
        for line in record.summary_lines(result):
            typer.echo(line)
        typer.echo(f"margin: {written}")
        if result.k_star is not None and result.k_star <= 1.0:
            raise NegativeVerdictError("a limit breaks at the measured timing (k* <= 1)")

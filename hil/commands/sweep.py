"""``hil sweep SCENARIO.toml --out DIR``: the loop over grids of Ts, delay, jitter and seeds."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from hil import interrupts
from hil.commands import ForceOpt, app
from hil.commands.new_law import LawOpt
from hil.errors import BadInputError, NegativeVerdictError
from hil.ticker import Ticker, start_line

if TYPE_CHECKING:  # the sweep's modules load when a sweep runs, not with the CLI
    from hil.sweep.cluster import ExecutorFacts
    from hil.sweep.outputs import SweepDocument, SweepMeta

DEFAULT_MAX_DURATION = 20.0
SWEEP_HELP = (
    "Run the scenario over the \\[sweep] grids on the batch path (one batch per Ts) and write "
    "sweep.html (the break point first, a heat map over Ts x delay, the results table), "
    "sweep.csv, sweep.json, sweep.md and PNG + CSV figures of tracking error, band width and "
    "constraint overshoot (max |v|/phi1, max |omega|/phi2) against Ts and delay, with the BREAK "
    "POINT: the smallest Ts / delay at which a limit of (2) broke.\n\n"
    "Default grid, for each axis the scenario and the options leave empty: "
    "ts = 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05 s; delay = 0, 0.002, 0.01, 0.05 s; "
    "jitter = 0; seeds = 1. Each loop runs the scenario's duration, at most 20 s unless "
    "--duration says otherwise.\n\n"
    'jitter_kind = "replay" with \\[timing] replay naming a run folder or .mcap (PATH::zenoh '
    "or PATH::can for one path) replays that run's measured latencies.\n\n"
    "Ctrl-C keeps the Ts groups already done and says which loops it did not cover (exit "
    "130). The break point is the sweep's answer, not a failure: exit 0 (PASS) also when a "
    "limit broke somewhere; 1 (FAIL) when the law faulted in a loop, or with --strict when "
    "any loop broke a limit; 2 on bad input (docs/reports.md)."
)


# The options of ``hil sweep`` longer than a line of its signature, one alias each.
ScenarioFileArg = Annotated[
    Path,
    typer.Argument(
        help="Scenario TOML or a bundled scenario's name (hil scenarios); its \\[sweep] "
        "table gives the grids."
    ),
]
OutOpt = Annotated[
    Path | None, typer.Option(help="Where to write (default: a new folder under runs/).")
]
DurationOpt = Annotated[
    float | None, typer.Option(help="Seconds per loop (default: the scenario's, at most 20 s).")
]
StrictOpt = Annotated[
    bool, typer.Option(help="FAIL (exit 1) when any loop of the grid broke a limit.")
]
WorstOpt = Annotated[
    bool,
    typer.Option(
        "--worst-disturbance",
        help="At every point, search the disturbance within |d1| <= s1, |d2| <= s2 that breaks "
        "(2) first (hil.adversary) instead of the scenario's own.",
    ),
]
WorkersOpt = Annotated[int | None, typer.Option(help="Run the grid's chunks on N local processes.")]
SchedulerOpt = Annotated[
    str | None,
    typer.Option(
        help="Run the grid's chunks on a Dask cluster, tcp://HOST:PORT of its scheduler "
        "(pip install 'hil-smc-bench[cluster]'; docs/reports.md)."
    ),
]
ChunkSizeOpt = Annotated[
    int | None, typer.Option(help="Grid points per chunk (default 64; same Ts in a chunk).")
]


@app.command("sweep", help=SWEEP_HELP)
def sweep(
    scenario_file: ScenarioFileArg,
    out: OutOpt = None,
    ts: Annotated[str | None, typer.Option(help="Ts grid, e.g. 0.001,0.01.")] = None,
    delay: Annotated[str | None, typer.Option(help="Delay grid in seconds.")] = None,
    jitter: Annotated[str | None, typer.Option(help="Jitter grid in seconds.")] = None,
    seeds: Annotated[int | None, typer.Option(help="Seeds per point.")] = None,
    duration: DurationOpt = None,
    strict: StrictOpt = False,
    law: LawOpt = None,
    worst_disturbance: WorstOpt = False,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    chunk_size: ChunkSizeOpt = None,
    force: ForceOpt = False,
) -> None:
    """Sweep the loop over grids of Ts, delay, jitter and seeds (help: SWEEP_HELP)."""
    from hil.folder import claim
    from hil.sweep import cluster

    scenario, grid, loop_s, latencies = _checked_sweep(
        scenario_file, out, ts, delay, jitter, seeds, duration, law, force
    )
    chunked = cluster.wanted(workers, scheduler, chunk_size)
    if chunked and worst_disturbance:
        raise BadInputError("--worst-disturbance runs in this process only (no chunks yet)")
    executor = cluster.open_executor(workers, scheduler, chunk_size) if chunked else None
    target = claim.take(out or Path("runs") / time.strftime("sweep-%Y%m%d-%H%M%S"), "sweep")
    claim.write_scenario(target, scenario)  # what ran, whole (docs/scenario.md)
    law = scenario.controller.get("law", "unified")
    what = f"{Path(scenario_file).name}, law {law}, {len(grid)} loops ({len(grid.ts)} Ts groups)"
    start_line("sweep", what, f"{loop_s:g} s simulated each", target)
    if latencies is not None:  # the run's latencies, replayed from replay.json in the folder
        from hil.folder.replay import write_latency_file

        t = scenario.timing
        lat = write_latency_file(latencies, target / "replay.json", scenario.base_dir / t.replay)
        replay = str(lat.resolve())
        scenario = dataclasses.replace(scenario, timing=dataclasses.replace(t, replay=replay))
    started = time.perf_counter()
    if executor is None:
        outcome, resolved = _run_with_progress(scenario, grid, loop_s, target, worst_disturbance)
        where: ExecutorFacts | None = None
    else:
        outcome, resolved, where = cluster.run_with_executor(
            scenario, grid, loop_s, target, executor, chunk_size
        )
    elapsed = time.perf_counter() - started
    from hil.sweep.outputs import write_outputs
    from hil.sweep.page import write_sweep_page

    meta = _meta(scenario, scenario_file, grid, loop_s, outcome, elapsed)
    meta.update(
        disturbance="worst searched" if worst_disturbance else "the scenario's",
        provenance=resolved.get("provenance", {}),
        **(where or {}),
    )
    # A second Ctrl-C while the results are written would leave them half-written.
    with interrupts.shielded():
        doc = write_outputs(target, outcome.rows, grid, meta)
        page = write_sweep_page(target, doc)
    typer.echo(f"sweep: {page} (also sweep.md, sweep.csv, sweep.json)")
    _say_and_judge(doc, outcome, target, strict, worst_disturbance)


def _say_and_judge(
    doc: SweepDocument, outcome: Any, target: Path, strict: bool, worst: bool
) -> None:
    """The sweep's lines (what it did not cover first, where the law failed, never "held
    everywhere" for a grid it did not cover or where the law failed), then its verdict's exit
    (hil.sweep.grid.sweep_outcome) or, interrupted, 130 through hil.cli."""
    from hil.sweep.grid import coverage_sentence, sweep_outcome

    bp = doc["break_point"]
    first, fault = bp.get("first"), bp.get("first_law_fault")
    missing = coverage_sentence(doc["coverage"])
    if missing:
        typer.echo(missing)
    if fault is not None:  # those points did not run to the end: never "held" there
        typer.echo(
            f"law fault at {bp['law_faults']} of {len(doc['rows'])} points (first at "
            f"Ts={fault['ts']:g} s, delay={fault['delay']:g} s): {fault['law_fault']}"
        )
    among = " among the loops run" if missing else ""
    if first is not None:
        typer.echo(f"break point{among}: Ts={first['ts']:g} s, delay={first['delay']:g} s")
    elif fault is not None:
        typer.echo(f"break point: none{among} where the law ran to the end")
    elif missing:
        typer.echo(f"break point: none{among}, no limit broke in the {len(doc['rows'])} loops run")
    else:
        typer.echo("break point: none, the limits held everywhere")
    if worst and first is not None:
        from hil.sweep.worst import worst_at_break

        typer.echo(f"broken by: {worst_at_break(outcome.rows, first)}")
    if outcome.interrupted:
        # hil.cli exits 130: the interrupt was recorded by hil.interrupts.
        interrupts.note(f"partial results kept in {target}")
        return
    verdict, why = sweep_outcome(outcome.rows, strict)
    if verdict != "PASS":
        raise NegativeVerdictError(f"{why}: {fault['law_fault']}" if fault else why, verdict)


def _checked_sweep(
    scenario_file: Path,
    out: Path | None,
    ts: str | None,
    delay: str | None,
    jitter: str | None,
    seeds: int | None,
    duration: float | None,
    law: str | None = None,
    force: bool = False,
) -> tuple[Any, Any, float, Any]:
    """The scenario, its grid, the loop length and the latencies of a run it replays (or
    None), every option and the scenario checked before any folder is written
    (BadInputError: exit 2)."""
    from hil import options
    from hil.analysis.replay import latencies_from_run
    from hil.bundled import resolve_scenario
    from hil.folder import claim
    from hil.folder.replay import is_run_source, jitter_samples_from
    from hil.law.batch import batch_note
    from hil.law.option import with_law
    from hil.scenario import (
        DELAY_MAX,
        DURATION_MAX,
        SWEEP_SEEDS_MAX,
        TS_MAX,
        TS_MIN,
        build_loop,
        check_loop_size,
        load_scenario,
    )
    from hil.sweep.grid import make_grid

    # Options first: a bad one is refused before the plotting and runner modules load.
    ts_grid = options.grid("--ts", ts, TS_MIN, TS_MAX)
    delay_grid = options.grid("--delay", delay, 0.0, DELAY_MAX)
    jitter_grid = options.grid("--jitter", jitter, 0.0, DELAY_MAX)
    if seeds is not None:
        options.integer("--seeds", seeds, 1, SWEEP_SEEDS_MAX)
    options.optional_number("--duration", duration, 0.0, DURATION_MAX, positive=True)
    claim.check("--out", out, force, default="runs")
    scenario = with_law(load_scenario(resolve_scenario(scenario_file)), law)
    sw = scenario.sweep
    try:
        grid = make_grid(
            ts_grid or sw.ts,
            delay_grid or sw.delay,
            jitter_grid or sw.jitter,
            seeds if seeds is not None else sw.seeds,
        )
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    loop_s = duration if duration is not None else min(scenario.run.duration, DEFAULT_MAX_DURATION)
    # Every loop of the grid within the simulator's sizes (control samples, plant steps per period).
    dur_name = "--duration" if duration is not None else "[run] duration"
    ts_name = "--ts" if ts_grid else "[sweep] ts"
    check_loop_size(scenario, dur_name, ts_name, loop_s, min(grid.ts), max(grid.ts))
    # A bad reference or design fails before any folder is written; a law that takes only
    # floats is found here too, and the user told it runs one robot at a time.
    controller, reference, _ = build_loop(scenario)
    note = batch_note(controller, scenario, reference)
    if note:
        typer.echo(note, err=True)
    t = scenario.timing
    latencies = None
    if t.jitter_kind == "replay" and is_run_source(scenario.base_dir / t.replay):
        latencies = latencies_from_run(scenario.base_dir / t.replay)
    elif t.jitter_kind == "replay":
        jitter_samples_from(scenario.base_dir / t.replay)  # a bad file fails here, named
    return scenario, grid, loop_s, latencies


def _run_with_progress(
    scenario: Any, grid: Any, loop_s: float, target: Path, worst: bool = False
) -> tuple[Any, Any]:
    """:func:`hil.sweep.runner.run_sweep` (or, ``worst``, :func:`hil.sweep.worst.
    run_worst_sweep`) under a progress bar counting robot-steps."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from hil.sweep.outputs import write_csv
    from hil.sweep.runner import run_sweep

    if worst:
        from hil.sweep.worst import run_worst_sweep as run_sweep

    counts = {float(v): max(1, round(loop_s / v)) for v in grid.ts}
    per_group = len(grid) // len(grid.ts)
    with Progress(
        TextColumn("[bold]sweep[/bold] {task.description}"),
        BarColumn(),
        TextColumn("{task.completed:,.0f}/{task.total:,.0f} robot-steps"),
        TimeRemainingColumn(),
        transient=False,
    ) as bar:
        task = bar.add_task(f"{len(grid)} loops", total=sum(counts.values()) * per_group)
        base: dict[float, int] = {}
        acc = 0
        tick = Ticker("hil sweep")

        def progress(ts_value: float, done: int, n: int, label: str = "") -> None:
            nonlocal acc
            if ts_value not in base:
                base[ts_value] = acc
                acc += counts[ts_value] * per_group
            completed = base[ts_value] + done * per_group
            # the grid point(s) running now (hil.sweep.grid.points_label), not only their Ts
            where = label or f"Ts = {ts_value:g} s"
            bar.update(task, completed=completed, description=where)
            total = sum(counts.values()) * per_group
            tick.tick(f"{where}, {100 * completed / max(total, 1):.0f}% of the robot-steps")

        # sweep.csv grows group by group, so even a killed sweep leaves what it finished.
        return run_sweep(
            scenario, grid, loop_s, progress, lambda rows: write_csv(target / "sweep.csv", rows)
        )


def _meta(
    scenario: Any, scenario_file: Path, grid: Any, loop_s: float, outcome: Any, elapsed: float
) -> SweepMeta:
    """What sweep.json says of the sweep beside its rows: the scenario, its law and limits
    (the page names them), the loop length, how far it got and how fast, the certificate."""
    from hil.sweep.runner import certified_break

    return {  # hil.sweep.outputs.SweepMeta
        "scenario_file": str(scenario_file),
        "law": str(scenario.controller.get("law", "unified")),
        "limits": {"phi1": scenario.limits.phi1, "phi2": scenario.limits.phi2},
        "duration": loop_s,
        "interrupted": outcome.interrupted,
        "groups_done": outcome.groups_done,
        "robot_steps": outcome.robot_steps,
        "elapsed_s": elapsed,
        "robot_steps_per_s": outcome.robot_steps / elapsed if elapsed > 0 else None,
        "certificate": certified_break(scenario, grid),
    }

"""``hil sim SCENARIO.toml --out DIR``: one offline closed loop, written as a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from hil import interrupts
from hil.commands import ForceOpt, app
from hil.commands.new_law import LawOpt
from hil.errors import NegativeVerdictError
from hil.ticker import Ticker, start_line


@app.command("sim")
def sim(
    scenario: Annotated[
        Path,
        typer.Argument(
            help="Scenario TOML file (docs/scenario.md) or a bundled scenario's name "
            "(hil scenarios)."
        ),
    ],
    out: Annotated[
        Path | None, typer.Option(help="Folder to write (default: runs/sim-<time>).")
    ] = None,
    duration: Annotated[float | None, typer.Option(help="Override [run] duration (s).")] = None,
    ts: Annotated[
        float | None, typer.Option(help="Override [timing] ts, the control period (s).")
    ] = None,
    law: LawOpt = None,
    force: ForceOpt = False,
) -> None:
    """Simulate one closed loop offline (law at Ts with zero-order hold, RK4 plant, delay and
    jitter as the scenario says) and write scenario.resolved.toml, trace.csv, summary.json.

    SCENARIO is a TOML file or the name of a bundled scenario (hil scenarios lists them).
    Ctrl-C writes the folder with what was computed and exits 130. Exit 1 when a limit of
    (2) was broken at some plant step, the robot's state became non-finite, or the law failed
    (raised, returned the wrong type or a non-finite torque: the folder then ends at that
    sample and law_fault.json says what happened; docs/own-controller.md)."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    from hil.analysis.replay import scenario_latencies
    from hil.bundled import resolve_scenario
    from hil.folder import claim, new_run_dir
    from hil.law.option import with_law
    from hil.scenario import build_loop, load_scenario
    from hil.sim import simulate, write_run_folder

    claim.check("--out", out, force, default="runs")
    path = resolve_scenario(scenario)
    sc = with_law(load_scenario(path), law).with_overrides(duration=duration, ts=ts)
    target = out or new_run_dir("runs", "sim")
    build_loop(sc)  # a law that cannot be built is refused before the start line (exit 2)
    # The start line; then a progress bar on stderr, or off a terminal a line every few
    # seconds (hil.ticker), so a script or a CI log can tell the work goes on.
    console = Console(stderr=True)
    quiet = not console.is_terminal
    law = sc.controller.get("law", "unified")
    what = f"{path.name}, law {law}, Ts = {sc.timing.ts:g} s (Ctrl-C writes what was computed)"
    start_line("sim", what, f"{sc.run.duration:g} s simulated", target)
    tick = Ticker("hil sim", enabled=quiet)
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeRemainingColumn(),
        console=console,
        transient=True,
        disable=quiet,
    ) as bar:
        task = bar.add_task(f"sim {path.name}", total=1)

        def progress(k: int, total: int) -> None:
            tick.tick(f"sample {k:,} of {total:,} ({100 * k / max(total, 1):.0f}%)")
            bar.update(task, completed=k, total=total)

        result = simulate(sc, progress=progress, replay=scenario_latencies(sc))
    with interrupts.shielded():  # a second Ctrl-C must not leave the folder half-written
        folder = write_run_folder(result, claim.take(target, "sim"))
    _finish(result, folder, sc.run.duration)


def _finish(result: Any, folder: Path, planned_s: float) -> None:
    """The simulation's result line, then its verdict's exit (a law's fault, a non-finite
    state, a broken limit: FAIL) or, interrupted, what it did not cover."""
    s = result.summary
    if result.interrupted:
        interrupts.note(
            f"at t = {s['duration']:.3f} s of {planned_s:g} s; wrote what was computed to "
            f"{folder} (no claim about the rest)"
        )
    _say_and_exit(folder, s)


def _say_and_exit(folder: Path, s: Any) -> None:
    """The simulation's line, then its verdict: the law's own failure or a state that became
    non-finite, else a broken limit of (2), exits 1."""
    from hil.verdict import law_ended

    typer.echo(
        f"{folder}: final position error {s['final_position_error']:.4g} m, heading "
        f"{s['final_heading_error']:.4g} rad; max |v| {s['max_abs_v']:.4g}, |omega| "
        f"{s['max_abs_omega']:.4g}, |tau1| {s['max_abs_tau1']:.4g}, |tau2| "
        f"{s['max_abs_tau2']:.4g}; violations {s['violations']}"
    )
    first = law_ended(s)  # the law's own failure, or a state that became non-finite
    if first is not None:
        raise NegativeVerdictError(str(first))
    if not s["limits_held"]:
        raise NegativeVerdictError(f"a limit of (2) was broken: violations {s['violations']}")

"""``hil sweep SCENARIO.toml --out DIR``: the loop over grids of Ts, delay, jitter and seeds."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Annotated

import typer

from hil import interrupts
from hil.errors import BadInputError, NegativeVerdictError

DEFAULT_MAX_DURATION = 20.0
SWEEP_HELP = (
    "Run the scenario over the \\[sweep] grids on the batch path (one batch per Ts) and write "
    "sweep.csv, sweep.json, sweep.md and PNG + CSV figures of tracking error, band width and "
    "constraint overshoot (max |v|/phi1, max |omega|/phi2) against Ts and delay, with the BREAK "
    "POINT: the smallest Ts / delay at which a limit of (2) broke.\n\n"
    "Default grid, for each axis the scenario and the options leave empty: "
    "ts = 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05 s; delay = 0, 0.002, 0.01, 0.05 s; "
    "jitter = 0; seeds = 1. Each loop runs the scenario's duration, at most 20 s unless "
    "--duration says otherwise.\n\n"
    'jitter_kind = "replay" with \\[timing] replay naming a run folder or .mcap (PATH::zenoh '
    "or PATH::can for one path) replays that run's measured latencies.\n\n"
    "Ctrl-C keeps the Ts groups already done (exit 130). Exit 0 (also when a break point is "
    "found, unless --strict), 1 with --strict when a limit broke, 2 on bad input."
)


def _floats(text: str | None, name: str) -> tuple[float, ...]:
    if not text:
        return ()
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError as exc:
        raise BadInputError(f"--{name}: expected comma-separated seconds, got {text!r}") from exc


def register(app: typer.Typer) -> None:
    @app.command("sweep", help=SWEEP_HELP)
    def sweep(
        scenario_file: Annotated[
            Path,
            typer.Argument(
                help="Scenario TOML or a bundled scenario's name (hil scenarios); its \\[sweep] "
                "table gives the grids."
            ),
        ],
        out: Annotated[
            Path | None,
            typer.Option("--out", help="Where to write (default: a new folder under runs/)."),
        ] = None,
        ts: Annotated[str | None, typer.Option(help="Ts grid, e.g. 0.001,0.01.")] = None,
        delay: Annotated[str | None, typer.Option(help="Delay grid in seconds.")] = None,
        jitter: Annotated[str | None, typer.Option(help="Jitter grid in seconds.")] = None,
        seeds: Annotated[int | None, typer.Option(help="Seeds per point.")] = None,
        duration: Annotated[
            float | None,
            typer.Option(help="Seconds per loop (default: the scenario's, at most 20 s)."),
        ] = None,
        strict: Annotated[
            bool, typer.Option(help="Exit 1 when any loop of the grid broke a limit.")
        ] = False,
    ) -> None:
        """Sweep the loop over grids of Ts, delay, jitter and seeds (help: SWEEP_HELP)."""
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        from hil.bundled import resolve_scenario
        from hil.scenario import load_scenario
        from hil.sweep.grid import make_grid
        from hil.sweep.outputs import write_csv, write_outputs
        from hil.sweep.replay import is_run_source, write_latency_file
        from hil.sweep.runner import certified_break, run_sweep

        scenario = load_scenario(resolve_scenario(scenario_file))
        sw = scenario.sweep
        try:
            grid = make_grid(
                _floats(ts, "ts") or sw.ts,
                _floats(delay, "delay") or sw.delay,
                _floats(jitter, "jitter") or sw.jitter,
                seeds if seeds is not None else sw.seeds,
            )
        except ValueError as exc:
            raise BadInputError(str(exc)) from exc
        loop_s = (
            duration if duration is not None else min(scenario.run.duration, DEFAULT_MAX_DURATION)
        )
        if not loop_s > 0:
            raise BadInputError(f"--duration must be > 0, got {loop_s}")
        target = out or Path("runs") / time.strftime("sweep-%Y%m%d-%H%M%S")
        target.mkdir(parents=True, exist_ok=True)
        t = scenario.timing
        if t.jitter_kind == "replay" and is_run_source(scenario.base_dir / t.replay):
            lat = write_latency_file(scenario.base_dir / t.replay, target / "replay.json")
            scenario = dataclasses.replace(
                scenario, timing=dataclasses.replace(t, replay=str(lat.resolve()))
            )
        counts = {float(v): max(1, round(loop_s / v)) for v in grid.ts}
        per_group = len(grid) // len(grid.ts)
        total = sum(counts.values()) * per_group
        started = time.perf_counter()
        with Progress(
            TextColumn("[bold]sweep[/bold] {task.description}"),
            BarColumn(),
            TextColumn("{task.completed:,.0f}/{task.total:,.0f} robot-steps"),
            TimeRemainingColumn(),
            transient=False,
        ) as bar:
            task = bar.add_task(f"{len(grid)} loops", total=total)
            base: dict[float, int] = {}
            acc = 0

            def progress(ts_value: float, done: int, n: int) -> None:
                nonlocal acc
                if ts_value not in base:
                    base[ts_value] = acc
                    acc += counts[ts_value] * per_group
                bar.update(
                    task,
                    completed=base[ts_value] + done * per_group,
                    description=f"Ts={ts_value:g} s",
                )

            # sweep.csv grows group by group, so even a killed sweep leaves what it finished.
            outcome, resolved = run_sweep(
                scenario, grid, loop_s, progress, lambda rows: write_csv(target / "sweep.csv", rows)
            )
        elapsed = time.perf_counter() - started
        meta = {
            "scenario_file": str(scenario_file),
            "law": str(scenario.controller.get("law", "unified")),
            "duration": loop_s,
            "interrupted": outcome.interrupted,
            "groups_done": outcome.groups_done,
            "robot_steps": outcome.robot_steps,
            "elapsed_s": elapsed,
            "robot_steps_per_s": outcome.robot_steps / elapsed if elapsed > 0 else None,
            "certificate": certified_break(scenario, grid),
            "provenance": resolved.get("provenance", {}),
        }
        # A second Ctrl-C while the results are written would leave them half-written.
        with interrupts.shielded():
            doc = write_outputs(target, outcome.rows, grid, meta)
        first = doc["break_point"].get("first")
        typer.echo(f"sweep: {target / 'sweep.md'}")
        typer.echo(
            "break point: none, the limits held everywhere"
            if first is None
            else f"break point: Ts={first['ts']:g} s, delay={first['delay']:g} s"
        )
        if outcome.interrupted:
            # hil.cli exits 130: the interrupt was recorded by hil.interrupts.
            interrupts.note(f"partial results kept in {target}")
            return
        if strict and first is not None:
            raise NegativeVerdictError("a limit of (2) broke inside the grid")

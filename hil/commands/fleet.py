"""``hil fleet SCENARIO --robots N``: N closed loops at once (hil.fleet, docs/fleet.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from hil import interrupts
from hil.commands.live_options import LiveHostOpt, live_opt
from hil.options import out_dir

LiveOpt = live_opt("every robot of the fleet, each on its own topics hil/robotI/...,")


def register(app: typer.Typer) -> None:
    @app.command("fleet")
    def fleet_cmd(
        scenario: Annotated[Path, typer.Argument(help="Scenario TOML or a bundled name.")],
        robots: Annotated[int, typer.Option(help="Number of robots (robot1..robotN).")] = 4,
        out: Annotated[
            Path, typer.Option(help="The fleet's folder (one run folder per robot).")
        ] = Path("runs/fleet"),
        duration: Annotated[float | None, typer.Option(help="Run length in s.")] = None,
        rate: Annotated[float | None, typer.Option(help="Control rate in Hz.")] = None,
        lab: Annotated[
            str | None,
            typer.Option(help="Run on this lab's hosts, all robots through its routers."),
        ] = None,
        plant_host: Annotated[str | None, typer.Option(help="The plants' lab host.")] = None,
        controller_host: Annotated[
            str | None, typer.Option(help="The controllers' lab host.")
        ] = None,
        per_process: Annotated[
            int,
            typer.Option(
                help="Robots per process: K robots' plants in one plant process and their "
                "controllers in one controller process (each robot its own keys, state, "
                "deadlines and run folder); 1: one `hil run` per robot."
            ),
        ] = 1,
        live: LiveOpt = None,
        live_host: LiveHostOpt = "127.0.0.1",
    ) -> None:
        """Run N robots' closed loops at once, each its own `hil run` with its own robot id
        (robotI: keys hil/robotI/...), controller, plant and run folder OUT/robotI (a complete
        run folder: `hil report OUT/robotI`), then write the fleet report OUT/fleet.json,
        fleet.md and fleet.png: per robot the verdict and D against D*; for the fleet the
        command age p99, the samples without a command and the deadline miss rate. Each robot
        is two processes (its plant, its controller) and a recorder, unless --per-process K
        groups K robots into one plant process, one controller process and one recorder
        (threads sharing a Zenoh session, each robot on its own keys hil/robotI/...): a
        2-core machine then fits about 32 robots at 100 Hz and 8 at 500 Hz (docs/fleet.md).
        --live serves every robot of the fleet on one Foxglove WebSocket server (docs/live.md).

        Exit 1 when a robot's verdict is negative."""
        from hil.bundled import resolve_scenario
        from hil.errors import NegativeVerdictError
        from hil.fleet import report
        from hil.fleet.run import FleetOptions, execute, robot_ids
        from runtime.signals import stop_on_signals

        out_dir("--out", out)
        opts = FleetOptions(
            resolve_scenario(scenario),
            robots,
            out,
            duration,
            rate,
            lab,
            plant_host,
            controller_host,
            per_process,
        )
        watcher = _live_watcher(out, robot_ids(robots), live, live_host, lab)
        with stop_on_signals() as stop:
            codes = execute(opts, stop, watcher)
            if stop:
                interrupts.record(stop.signal)
        facts = {"scenario": str(opts.scenario), "rate_hz": rate, "duration_s": duration}
        facts["lab"] = lab
        facts["per_process"] = per_process
        summary = report.write(out, codes, facts)
        typer.echo(json.dumps(summary["fleet"], indent=2))
        if stop:
            interrupts.note(f"fleet folder written to {out}")
            return
        bad = [r["robot"] for r in summary["per_robot"] if r.get("exit_code") not in (0,)]
        if bad:
            raise NegativeVerdictError(
                f"robots with a negative verdict or an error: {', '.join(bad)}"
            )


def _live_watcher(
    out: Path, robots: list[str], live: int | None, live_host: str, lab: str | None
) -> Any:
    """The fleet's live view (None without --live), its port checked first."""
    from hil.live.launch import FleetLive
    from hil.live.launch import check as live_check

    live_check(live, live_host)
    return None if live is None else FleetLive(out, robots, live, live_host, lab is not None)

"""``hil fleet SCENARIO --robots N``: N closed loops at once (hil.bench.fleet, docs/fleet.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from hil import interrupts
from hil.bundled import resolve_scenario
from hil.commands import ForceOpt, app
from hil.commands.new_law import LawOpt
from hil.commands.run import LiveHostOpt, live_opt
from hil.errors import NegativeVerdictError
from hil.options import out_dir
from hil.ticker import start_line

FleetLiveOpt = live_opt("every robot of the fleet, each on its own topics hil/robotI/...,")


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
        str | None, typer.Option(help="Run on this lab's hosts, all robots through its routers.")
    ] = None,
    plant_host: Annotated[str | None, typer.Option(help="The plants' lab host.")] = None,
    controller_host: Annotated[str | None, typer.Option(help="The controllers' lab host.")] = None,
    per_process: Annotated[
        int,
        typer.Option(
            help="Robots per process: K robots' plants in one plant process and their "
            "controllers in one controller process (each robot its own keys, state, "
            "deadlines and run folder); 1: one `hil run` per robot."
        ),
    ] = 1,
    live: FleetLiveOpt = None,
    live_host: LiveHostOpt = "127.0.0.1",
    law: LawOpt = None,
    force: ForceOpt = False,
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

    The fleet's verdict is its robots': FAIL (exit 1) when a robot's is FAIL or its run left
    no verdict, else INCONCLUSIVE (exit 4) when a robot's is, else PASS (exit 0)."""
    from hil.analysis import fleet_report as report
    from hil.bench.fleet.spawner import FleetOptions, check, execute, robot_ids
    from hil.bench.live import launch
    from hil.bench.prepare import RunOptions
    from hil.law.option import with_law
    from hil.scenario import build_loop, load_scenario
    from runtime.signals import stop_on_signals

    out_dir("--out", out)
    path = resolve_scenario(scenario)
    run = RunOptions(scenario=path, duration=duration, rate=rate, law=law, lab=lab)
    run.plant_host, run.controller_host = plant_host, controller_host
    opts = FleetOptions(run, robots, out, per_process, force)
    launch.check(live, live_host)  # the port, before any robot starts
    check(opts)  # the options, the folder and the law, before the start line
    sc = with_law(load_scenario(path), law)
    build_loop(sc)  # a law that cannot be built is refused here, not by every robot
    ids = robot_ids(robots)
    what = f"{path.name}, law {sc.controller.get('law', 'unified')}, {robots} robots"
    what += f" ({per_process} a process), each its own hil run"
    long = f"{duration:g} s each" if duration is not None else "the scenario's duration each"
    start_line("fleet", what, long, out)
    watcher = None if live is None else launch.FleetLive(out, ids, live, live_host, lab is not None)
    with stop_on_signals() as stop:
        codes = execute(opts, stop, watcher)
        if stop:
            interrupts.record(stop.signal)
    facts: report.FleetFacts = {"scenario": str(path), "rate_hz": rate, "duration_s": duration}
    facts.update(lab=lab, per_process=per_process)
    summary = report.write(out, codes, facts)
    typer.echo(json.dumps(summary["fleet"], indent=2))
    if stop:
        interrupts.note(f"fleet folder written to {out}")
        return
    f = summary["fleet"]
    if f["verdict"] != "PASS":  # the fleet's verdict's exit code (hil.analysis.fleet_report)
        raise NegativeVerdictError(report.negative_reason(summary), f["verdict"])

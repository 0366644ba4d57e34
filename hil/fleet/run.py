"""N robots' closed loops at once: one ``hil run`` per robot, each with its own robot id
(``robot1`` .. ``robotN``: its own keys ``hil/robotI/...``), its own controller and plant
processes and its own run folder, all started together and stopped together.

Over loopback each robot's sessions form their own peer mesh (one Zenoh session per process,
as separate robots would have); with ``--lab`` every process is a client of its lab host's
router, so all robots' traffic crosses the same routers (hil.lab.placement).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.errors import BadInputError
from hil.fleet import barrier
from hil.supervisor import Supervisor

ROBOTS_MAX = 64


@dataclass
class FleetOptions:
    scenario: Path
    robots: int
    out: Path
    duration: float | None = None
    rate: float | None = None
    lab: str | None = None
    plant_host: str | None = None
    controller_host: str | None = None


def robot_ids(n: int) -> list[str]:
    return [f"robot{i}" for i in range(1, n + 1)]


def run_argv(opts: FleetOptions, robot: str) -> list[str]:
    """``hil run`` of one robot of the fleet."""
    argv = [sys.executable, "-m", "hil", "run", str(opts.scenario), "--robot-id", robot]
    argv += ["--out", str(opts.out / robot), "--quiet", "--no-report", "--no-can"]
    if opts.duration is not None:
        argv += ["--duration", repr(opts.duration)]
    if opts.rate is not None:
        argv += ["--rate", repr(opts.rate)]
    if opts.lab:
        argv += ["--lab", opts.lab]
        for flag, host in (
            ("--plant-host", opts.plant_host),
            ("--controller-host", opts.controller_host),
        ):
            if host:
                argv += [flag, host]
    return argv


def check(opts: FleetOptions) -> None:
    if not 1 <= opts.robots <= ROBOTS_MAX:
        raise BadInputError(f"--robots {opts.robots}: 1 to {ROBOTS_MAX}")
    if opts.out.exists() and any(opts.out.iterdir()):
        raise BadInputError(f"--out {opts.out}: exists and is not empty")


def execute(opts: FleetOptions, stop: Any) -> dict[str, int | None]:
    """Start every robot's ``hil run`` at once and wait for all (or for ``stop``: then each
    gets SIGINT and writes its folder); the exit code of each."""
    check(opts)
    opts.out.mkdir(parents=True, exist_ok=True)
    sup = Supervisor()
    logs = []
    try:
        for robot in robot_ids(opts.robots):
            log = (opts.out / f"{robot}.log").open("wb")
            logs.append(log)
            env = barrier.env_for(opts.out, opts.robots, robot)
            sup.start(robot, run_argv(opts, robot), env=env, stdout=log, stderr=log)
        while not stop and any(c.alive() for c in sup.children):
            for c in sup.children:
                if not c.alive():  # ended before the start (it may never have been ready)
                    barrier.release(opts.out, c.name)
            time.sleep(0.1)
    finally:
        # A run that is still going gets SIGINT (it stops its services and writes its folder).
        codes = {c.name: c.stop(grace=60.0) for c in sup.children}
        for log in logs:
            log.close()
    return codes

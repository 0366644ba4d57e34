"""N robots' closed loops at once (docs/fleet.md): one ``hil run`` per robot ``robot1`` ..
``robotN`` or, with ``--per-process K`` (K > 1), one ``python -m hil.commands.group`` per group of K
robots; all started together and stopped together.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil import ticker
from hil.bench.fleet import barrier
from hil.bench.group import GroupSpec
from hil.bench.lab import placement
from hil.bench.prepare import RunOptions
from hil.bench.supervisor import Supervisor
from hil.errors import BadInputError
from hil.folder import claim, layout

ROBOTS_MAX = 64


@dataclass
class FleetOptions:
    """``hil fleet``'s options: every robot's ``hil run`` options (``run``: its scenario,
    duration, rate, law, lab hosts) and the fleet's own."""

    run: RunOptions
    robots: int
    out: Path
    per_process: int = 1  # robots per plant and per controller process
    force: bool = False  # --force: replace a folder that holds files (hil.folder.claim)

    def robot(self, robot: str) -> RunOptions:
        """One robot's ``hil run`` (:meth:`hil.bench.prepare.RunOptions.fleet_robot`)."""
        return self.run.fleet_robot(robot, self.out)


def robot_ids(n: int) -> list[str]:
    return [f"robot{i}" for i in range(1, n + 1)]


def run_argv(opts: FleetOptions, robot: str) -> list[str]:
    """``hil run`` of one robot of the fleet (its report is the fleet's)."""
    return [sys.executable, "-m", "hil", "run", *opts.robot(robot).argv(), "--no-report"]


def group_argv(opts: FleetOptions, robots: list[str]) -> list[str]:
    """``python -m hil.commands.group`` of one group, its spec written into the fleet's folder."""
    spec = GroupSpec(opts.run, robots, opts.out, fleet_size=opts.robots)
    path = opts.out / layout.group_spec(robots[0])
    spec.write(path)
    return [sys.executable, "-m", "hil.commands.group", str(path)]


def group_codes(opts: FleetOptions, robots: list[str], code: int | None) -> dict[str, int | None]:
    """Each robot's exit code from its group's file (the group's own code for a robot the
    file does not have: the group ended before it wrote it)."""
    try:
        got = json.loads((opts.out / layout.group_codes(robots[0])).read_text())
    except (OSError, ValueError):
        got = {}
    return {r: got.get(r, code if code else 1) for r in robots}


def check(opts: FleetOptions) -> None:
    for flag, n in (("--robots", opts.robots), ("--per-process", opts.per_process)):
        if not 1 <= n <= ROBOTS_MAX:
            raise BadInputError(f"{flag} {n}: 1 to {ROBOTS_MAX}")
    claim.check("--out", opts.out, opts.force)
    placement.placement_of(opts.robot("robot1"))  # --plant-host without --lab, and the like


def execute(opts: FleetOptions, stop: Any, live: Any = None) -> dict[str, int | None]:
    """Start every robot's ``hil run`` at once and wait for all (or for ``stop``: then each
    gets SIGINT and writes its folder); the exit code of each. ``live``: polled, then closed."""
    check(opts)
    claim.take(opts.out, "fleet")
    sup = Supervisor()
    logs = []
    ids, k = robot_ids(opts.robots), opts.per_process  # k robots a process (check: 1..64)
    members = {ids[i]: ids[i : i + k] for i in range(0, len(ids), k)}  # by each group's first
    grouped = opts.per_process > 1
    try:
        for first, robots in members.items():
            log = (opts.out / f"{first}.log").open("wb")
            logs.append(log)
            env = barrier.env_for(opts.out, opts.robots, first)
            argv = group_argv(opts, robots) if grouped else run_argv(opts, first)
            sup.start(first, argv, env=env, stdout=log, stderr=log)
        tick, t0 = ticker.Ticker("hil fleet", enabled=True), time.monotonic()
        while not stop and any(c.alive() for c in sup.children):
            running = sum(c.alive() for c in sup.children)
            tick.tick(
                f"{time.monotonic() - t0:.0f} s, {running} of {len(members)} processes running"
            )
            if live is not None:
                live.poll()
            for c in sup.children:
                if not c.alive():  # ended before the start (it may never have been ready)
                    for robot in members[c.name]:
                        barrier.release(opts.out, robot)
            time.sleep(0.1)
    finally:
        # A run that is still going gets SIGINT (it stops its services and writes its folder).
        codes = {c.name: c.stop(grace=60.0 + 5.0 * len(members[c.name])) for c in sup.children}
        for log in logs:
            log.close()
        if live is not None:
            live.close()
    if not grouped:
        return codes
    return {
        r: c
        for first, code in codes.items()
        for r, c in group_codes(opts, members[first], code).items()
    }

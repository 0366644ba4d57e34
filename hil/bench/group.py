"""Several robots' closed loops in three processes, for a fleet on a 2-core machine (``hil fleet
--per-process K``): recorded here, each robot's folder then analysed by the group's process,
``python -m hil.commands.group SPEC.json``.

Each robot keeps its own run folder (``OUT/robotI``, its keys' recording included), so
``hil report`` reads it unchanged and every figure keeps its definition; the K robots share one
plant process, one controller process (runtime.group) and this recorder (docs/fleet.md), in the
lifecycle ``hil run`` has for one (:func:`hil.bench.lifecycle.record_robots`). Their epochs are
interleaved (:func:`hil.bench.lifecycle.phase_ns`) so their deadlines do not all fall on the
same instant.
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.bench.host_load import HostSampler
from hil.bench.lifecycle import (
    Recording,
    RobotRun,
    RunError,
    record_robots,
    start_and_follow,
    start_services,
)
from hil.bench.prepare import RunOptions, free_port, prepare
from hil.bench.recorder import Recorder, RecordingWriter
from hil.bench.secure import RunIdentities
from hil.folder import layout
from hil.folder.records import ControllerExit, Recorded
from hil.folder.replay import RunLatencies


@dataclass
class GroupSpec:
    """One group of a fleet: its robots' ``hil run`` options, its robots, the fleet's folder."""

    run: RunOptions  # every robot's options (hil.bench.fleet.spawner.FleetOptions.robot)
    robots: list[str]
    out: Path
    fleet_size: int = 0  # N: robot I's epoch is shifted by (I - 1) / N of a period

    def options(self, robot: str | None = None) -> RunOptions:
        """One robot's options (``robot`` None: the group's, as for its lab placement)."""
        return self.run.fleet_robot(robot, self.out)

    def write(self, path: Path) -> None:
        doc = {"run": self.run.to_json(), "robots": self.robots, "out": str(self.out)}
        doc["fleet_size"] = self.fleet_size
        path.write_text(json.dumps(doc, indent=2) + "\n")

    @classmethod
    def read(cls, path: Path) -> GroupSpec:
        """The spec :meth:`write` wrote (by hil fleet, for the group's process)."""
        doc = json.loads(path.read_text())
        run = RunOptions.from_json(doc["run"])
        return cls(run, list(doc["robots"]), Path(doc["out"]), int(doc["fleet_size"]))


def _prepare(
    spec: GroupSpec, endpoint: str | None, run_latencies: RunLatencies | None
) -> list[RobotRun]:
    """Each robot's run folder as ``hil run --robot-id R --no-can`` prepares it, on the group's
    one endpoint (None: a lab host's router, whose services' clocks are not the recorder's)."""
    robots = []
    for r in spec.robots:
        opts = spec.options(r)
        opts.run_latencies = run_latencies
        scenario, settings, run_dir, design = prepare(opts)
        settings.zenoh_endpoint = endpoint or settings.zenoh_endpoint
        settings.save(run_dir / layout.RUN_SETTINGS)
        meta = {"robot_id": r, "cmd_path": settings.cmd_path, "lockstep": settings.lockstep}
        meta.update({"rate_hz": design.rate_hz, "group": ",".join(spec.robots)})
        writer = RecordingWriter(run_dir / layout.RECORDING, metadata=meta)
        recorder = Recorder(writer, same_clock=endpoint is not None)
        robots.append(RobotRun(scenario, settings, run_dir, design, recorder))
    return robots


def record(
    spec: GroupSpec, stop: Any, placed: Any = None, run_latencies: RunLatencies | None = None
) -> list[Recorded]:
    """Run the group (``placed``: on a lab's hosts, this process on the recorder's); each
    robot's raw run folder, for the analysis (:mod:`hil.commands.group`). ``run_latencies``:
    as :class:`hil.bench.prepare.RunOptions`'."""
    out = spec.out
    out.mkdir(parents=True, exist_ok=True)
    endpoint = None if placed else f"tcp/127.0.0.1:{free_port()}"
    robots = _prepare(spec, endpoint, run_latencies)
    rec = Recording(robots, RunIdentities(False, [r.id for r in robots]), out, placed, group=True)
    # The processes' console logs are the group's, in the fleet's folder.
    prefix = f"{robots[0].id}-group-"

    def follow(rec: Recording, session: Any, logs: Any, host: HostSampler,
               held: contextlib.ExitStack) -> tuple[RunError | None, ControllerExit | None]:  # fmt: skip  # noqa: E501
        start_services(rec.sup, [r.run_dir for r in robots], rec.ids, logs, host, placed, prefix)
        n = spec.fleet_size or len(robots)
        output = f"../{prefix}{layout.CONTROLLER_OUTPUT}"
        return start_and_follow(rec, stop, session, True, fleet_size=n, output=output)

    record_robots(rec, stop, follow)
    return [r.recorded(extra) for r, extra in zip(robots, rec.extra(bool(stop)), strict=True)]

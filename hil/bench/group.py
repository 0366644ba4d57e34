"""Several robots' closed loops in three processes, for a fleet on a 2-core machine (``hil fleet
--per-process K``): recorded here, each robot's folder then analysed by the group's process,
``python -m hil.commands.group SPEC.json``.

Each robot keeps its own run folder (``OUT/robotI``, its keys' recording included), so
``hil report`` reads it unchanged and every figure keeps its definition; the K robots share one
plant process, one controller process (runtime.group) and this recorder (docs/fleet.md). Their
epochs are interleaved (:func:`phase_ns`) so their deadlines do not all fall on the same instant.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.bench.fleet import barrier as fleet_barrier
from hil.bench.host_load import HostSampler
from hil.bench.lab import placement
from hil.bench.lifecycle import (
    LAB_ROUTER,
    RunOptions,
    _Logs,
    _progress,
    _start_services,
    _stop_children,
    _wait_ready,
    attachment_files,
    free_port,
    prepare,
    run_extra,
)
from hil.bench.recorder import Recorder, RecordingWriter
from hil.bench.secure import RunIdentities
from hil.bench.supervisor import Supervisor
from hil.folder import layout
from hil.folder.records import ControllerExit, Recorded
from hil.folder.replay import RunLatencies
from protocol.keys import observed_keys
from protocol.settings import RunSettings, period_ns
from runtime.startgate import announce_start
from runtime.zsession import open_session

START_GRID_NS = 500_000_000


@dataclass
class GroupSpec:
    """One group of a fleet: its robots, the fleet's folder and the run's options."""

    scenario: str
    robots: list[str]
    out: str
    duration: float | None = None
    rate: float | None = None
    fleet_size: int = 0  # N: robot I's epoch is shifted by (I - 1) / N of a period
    lab: str | None = None  # on a lab's hosts (hil.bench.lab.placement), through their routers
    plant_host: str | None = None
    controller_host: str | None = None
    law: str | None = None  # hil fleet --law

    def options(self, robot: str | None = None) -> RunOptions:
        """``hil run``'s options for one robot of the group (``--no-can``, quiet)."""
        opts = RunOptions(scenario=Path(self.scenario), duration=self.duration, rate=self.rate)
        opts.quiet, opts.can_live, opts.robot_id = True, False, robot
        opts.law = self.law
        opts.out = None if robot is None else Path(self.out) / robot
        for key in ("lab", "plant_host", "controller_host"):
            setattr(opts, key, getattr(self, key))
        return opts


@dataclass
class _Robot:
    id: str
    scenario: Any
    settings: RunSettings
    run_dir: Path
    info: dict[str, Any]
    recorder: Recorder


def _prepare(
    spec: GroupSpec, endpoint: str | None, run_latencies: RunLatencies | None
) -> list[_Robot]:
    """Each robot's run folder as ``hil run --robot-id R --no-can`` prepares it, on the group's
    one endpoint (None: a lab host's router, whose services' clocks are not the recorder's)."""
    robots = []
    for r in spec.robots:
        opts = spec.options(r)
        opts.run_latencies = run_latencies
        scenario, settings, run_dir, info = prepare(opts)
        settings.zenoh_endpoint = endpoint or settings.zenoh_endpoint
        settings.save(run_dir / layout.RUN_SETTINGS)
        meta = {"robot_id": r, "cmd_path": settings.cmd_path, "lockstep": settings.lockstep}
        meta.update({"rate_hz": info["rate_hz"], "group": ",".join(spec.robots)})
        writer = RecordingWriter(run_dir / layout.RECORDING, metadata=meta)
        recorder = Recorder(writer, same_clock=endpoint is not None)
        robots.append(_Robot(r, scenario, settings, run_dir, info, recorder))
    return robots


def phase_ns(robot: str, position: int, n: int, period: int) -> int:
    """Robot I's epoch shift, (I - 1) / N of a period (I: from ``robotI``, else its position)."""
    m = re.fullmatch(r"robot(\d+)", robot)
    index = int(m.group(1)) - 1 if m else position
    return period * (index % n) // n if n > 0 else 0


def _start_and_follow(spec: GroupSpec, robots: list[_Robot], sup: Supervisor, session: Any,
                      stop: Any) -> tuple[str | None, ControllerExit | None]:  # fmt: skip
    """Wait until every robot's plant and controller are ready, start them together (with
    the rest of the fleet), follow the run to its end; returns an error (or None) and how the
    group's controller process ended when it ended first (or None)."""
    deadline = time.monotonic() + float(os.environ.get("HIL_READY_TIMEOUT", "300"))
    for r in robots:
        if not _wait_ready(r.recorder, sup, stop, max(0.0, deadline - time.monotonic())):
            return f"services of {r.id} did not become ready", None
    barrier = os.environ.get(fleet_barrier.ENV)
    if barrier:  # every robot of this group is ready
        for r in robots:
            fleet_barrier.release(Path(barrier.rsplit(":", 2)[0]), r.id)
    fleet_barrier.wait(stop)
    # On a grid: the fleet's groups, released together within the barrier's poll, pick the
    # same base (one host, one clock), so the phases interleave across groups too.
    base = -(-(time.monotonic_ns() + 300_000_000) // START_GRID_NS) * START_GRID_NS
    n = spec.fleet_size or len(robots)
    epochs = [base + phase_ns(r.id, i, n, period_ns(r.settings.ts)) for i, r in enumerate(robots)]
    for seq in range(3):  # a start message lost to a racing link must not hang
        for r, epoch in zip(robots, epochs, strict=True):
            announce_start(session, r.id, epoch, seq=seq)
        time.sleep(0.02)
    # The process's console log is the group's, in the fleet's folder.
    output = f"../{robots[0].id}-group-{layout.CONTROLLER_OUTPUT}"
    return None, _progress(robots[0].settings, robots[0].recorder, sup, stop, True, base, output)


def record(
    spec: GroupSpec, stop: Any, placed: Any = None, run_latencies: RunLatencies | None = None
) -> list[Recorded]:
    """Run the group (``placed``: on a lab's hosts, this process on the recorder's); each
    robot's raw run folder, for the analysis (:mod:`hil.commands.group`). ``run_latencies``:
    as :class:`hil.bench.lifecycle.RunOptions`'."""
    out = Path(spec.out)
    out.mkdir(parents=True, exist_ok=True)
    endpoint = None if placed else f"tcp/127.0.0.1:{free_port()}"
    robots = _prepare(spec, endpoint, run_latencies)
    sup, logs = Supervisor(), _Logs(out)
    host = HostSampler(robots[0].run_dir)
    session, subs, error, ended = None, [], None, None
    t0 = time.monotonic()
    try:
        if placed:  # the client of the lab host's own router, as hil run --lab
            session = open_session(LAB_ROUTER, mode="client", credentials=None)
        else:
            session = open_session(endpoint, listen_endpoint=True, credentials=None)
        for r in robots:  # each robot's status and taps into its own recording
            subs += [
                session.declare_subscriber(k, r.recorder.on_zenoh) for k in observed_keys(r.id)
            ]
        ids = RunIdentities(False, [r.id for r in robots])
        run_dirs = [r.run_dir for r in robots]
        _start_services(sup, run_dirs, ids, logs, host, placed, f"{robots[0].id}-group-")
        error, ended = _start_and_follow(spec, robots, sup, session, stop)
    finally:
        codes = _stop_children(sup, robots[0].settings)
        host.close()
        logs.close()
        for sub in subs:
            sub.undeclare()
        if session is not None:
            session.close()
        for r in robots:
            if r is not robots[0] and (robots[0].run_dir / layout.HOST_LOG).is_file():
                shutil.copyfile(robots[0].run_dir / layout.HOST_LOG, r.run_dir / layout.HOST_LOG)
            placement.write_topology(placed, r.run_dir)  # before the recording takes it along
            r.recorder.close(attachment_files(r.run_dir))
    return _recorded(spec, robots, codes, error, bool(stop), time.monotonic() - t0, ended)


def _recorded(spec: GroupSpec, robots: list[_Robot], codes: dict[str, int | None],
              error: str | None, interrupted: bool, wall: float,
              ended: ControllerExit | None = None) -> list[Recorded]:  # fmt: skip
    """Each robot's run as ``hil run`` records it, with what the group shares."""
    out = []
    shared = {"robots": list(spec.robots), "processes": ["plant", "controller"]}
    for r in robots:
        extra = run_extra(interrupted, error, wall, codes, r.recorder, False)
        extra["shared_processes"] = shared
        if ended is not None:  # the process ended: every robot it served lost its controller
            extra["controller_exit"] = ended
        out.append(Recorded(r.run_dir, r.scenario, r.settings, r.info["reference"],
                            r.info["context"], extra))  # fmt: skip
    return out

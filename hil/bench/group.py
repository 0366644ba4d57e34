"""``python -m hil.bench.group SPEC.json``: several robots' closed loops in three processes, for a
fleet on a 2-core machine (``hil fleet --per-process K``).

Each robot keeps its own run folder (``OUT/robotI``, its keys' recording included), so
``hil report`` reads it unchanged and every figure keeps its definition; the K robots share one
plant process, one controller process (runtime.group) and this recorder (docs/fleet.md). Their
epochs are interleaved (:func:`phase_ns`) so their deadlines do not all fall on the same instant.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.analysis.measure.logs import HOST_FILE
from hil.bench.fleet import barrier as fleet_barrier
from hil.bench.host_load import HostSampler
from hil.bench.lab import placement
from hil.bench.lifecycle import (
    LAB_ROUTER,
    Recorder,
    RunOptions,
    _Logs,
    _progress,
    _start_services,
    _stop_children,
    _wait_ready,
    _write_results,
    attachment_files,
    free_port,
    prepare,
    run_extra,
)
from hil.bench.secure import RunIdentities
from hil.bench.supervisor import Supervisor
from hil.folder import layout
from hil.folder.recording import RecordingWriter
from hil.folder.records import ControllerExit
from hil.verdict import FAIL, INCONCLUSIVE, INTERRUPTED, PASS, exit_code, run_outcome
from protocol.keys import observed_keys
from protocol.settings import RunSettings, period_ns
from runtime.signals import stop_on_signals
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

    def options(self, robot: str | None = None) -> RunOptions:
        """``hil run``'s options for one robot of the group (``--no-can``, quiet)."""
        opts = RunOptions(scenario=Path(self.scenario), duration=self.duration, rate=self.rate)
        opts.quiet, opts.can_live, opts.robot_id = True, False, robot
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


def _prepare(spec: GroupSpec, endpoint: str | None) -> list[_Robot]:
    """Each robot's run folder as ``hil run --robot-id R --no-can`` prepares it, on the group's
    one endpoint (None: a lab host's router, whose services' clocks are not the recorder's)."""
    robots = []
    for r in spec.robots:
        scenario, settings, run_dir, info = prepare(spec.options(r))
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


def execute(spec: GroupSpec, stop: Any, placed: Any = None) -> dict[str, int]:
    """Run the group (``placed``: on a lab's hosts, this process on the recorder's); each
    robot's exit code (also written to ``OUT/.group-<first robot>.codes.json``)."""
    out = Path(spec.out)
    out.mkdir(parents=True, exist_ok=True)
    endpoint = None if placed else f"tcp/127.0.0.1:{free_port()}"
    robots = _prepare(spec, endpoint)
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
            if r is not robots[0] and (robots[0].run_dir / HOST_FILE).is_file():
                shutil.copyfile(robots[0].run_dir / HOST_FILE, r.run_dir / HOST_FILE)
            placement.write_topology(placed, r.run_dir)  # before the recording takes it along
            r.recorder.close(attachment_files(r.run_dir))
    return _results(spec, robots, codes, error, bool(stop), time.monotonic() - t0, ended)


def _results(spec: GroupSpec, robots: list[_Robot], codes: dict[str, int | None],
             error: str | None, interrupted: bool, wall: float,
             ended: ControllerExit | None = None) -> dict[str, int]:  # fmt: skip
    """Each robot's trace.csv, summary.json and plots, as ``hil run`` writes them."""
    out: dict[str, int] = {}
    shared = {"robots": list(spec.robots), "processes": ["plant", "controller"]}
    for r in robots:
        extra = run_extra(interrupted, error, wall, codes, r.recorder, False)
        extra["shared_processes"] = shared
        if ended is not None:  # the process ended: every robot it served lost its controller
            extra["controller_exit"] = ended
        summary = _write_results(r.run_dir, r.scenario, r.settings, r.info, extra)
        # The exit code hil run gives this summary (hil.commands.run).
        out[r.id] = exit_code(run_outcome(summary))
    # Where hil fleet reads each robot's exit code (as ``hil run`` would exit for it).
    (Path(spec.out) / f".group-{spec.robots[0]}.codes.json").write_text(json.dumps(out) + "\n")
    return out


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m hil.bench.group SPEC.json (written by hil fleet)", file=sys.stderr)
        return 2
    spec = GroupSpec(**json.loads(Path(args[0]).read_text()))
    # --lab: executes this same command again on the recorder's lab host (as hil run does).
    placed = placement.enter(spec.options(), False, True)
    with stop_on_signals() as stop:
        codes = execute(spec, stop, placed)
    if stop:
        return INTERRUPTED
    # The group's worst robot: any FAIL, else any INCONCLUSIVE (hil fleet reads each robot's).
    for outcome in (FAIL, INCONCLUSIVE):
        if exit_code(outcome) in codes.values():
            return exit_code(outcome)
    return exit_code(PASS)


if __name__ == "__main__":
    sys.exit(main())

"""``hil run``: start the pair (and a router if asked), record everything, write the folder
(:mod:`hil.bench.prepare` wrote its first files). One lifecycle for K robots
(:func:`record_robots`): ``hil run`` is K = 1, a fleet's group (:mod:`hil.bench.group`) K > 1.

The children die with this process (PR_SET_PDEATHSIG) and are stopped by PID, the controller
first, with SIGINT so they flush their logs. Ctrl-C or SIGTERM at any point still stops
everything and writes the summary.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import os
import re
import shutil
import signal
import socket
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from subprocess import STDOUT
from typing import Any

import can
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from hil import interrupts, ticker
from hil.bench import device, impair
from hil.bench.defaults import ready_timeout_s
from hil.bench.fleet import barrier as fleet_barrier
from hil.bench.host_load import HostSampler
from hil.bench.lab import placement
from hil.bench.lab.placement import child_argv
from hil.bench.live.launch import start_for_run
from hil.bench.prepare import LoopDesign, RunOptions, check_options, prepare
from hil.bench.recorder import Recorder, RecordingWriter
from hil.bench.secure import RunIdentities
from hil.bench.supervisor import Supervisor
from hil.bundled import resolve_scenario
from hil.folder import layout
from hil.folder.records import ControllerExit, Recorded, RunExtra
from hil.scenario import (
    Scenario,
    load_scenario,
)
from protocol.can.rx_queue import RxQueueDrops
from protocol.hoplog import LAW_FAULT_EXIT
from protocol.keys import observed_keys, state_key
from protocol.settings import RunSettings, period_ns
from runtime.signals import stop_on_signals
from runtime.startgate import announce_start
from runtime.zsession import open_session


def _can_recorder(
    settings: RunSettings, recorder: Recorder, also: Callable[[Any], None] | None = None
) -> tuple[Any, Any, Any] | None:
    """A python-can Notifier on the run's bus feeding the recorder (and ``also``: an outside
    device's arrival), and the drop count of its receiving socket (protocol.can.rx_queue;
    None if no CAN)."""
    try:
        bus = settings.open_can_bus()
        if bus is None:
            return None
        channel = str(settings.can.get("channel", "can"))
        drops = RxQueueDrops(bus)
        listeners: list[Callable[[Any], None]] = [lambda m: recorder.on_can(channel, m)]
        if also is not None:
            listeners.append(also)
        return bus, can.Notifier(bus, listeners, timeout=0.1), drops
    except Exception as exc:
        print(f"warning: CAN recording off: {exc}", file=sys.stderr)
        return None


def _open_recorder_session(rec: Recording, logs: _Logs, stop: Any) -> Any:
    """The recorder's Zenoh session: the client of the lab host's own router, or of the
    run's router (started here), or a peer on the run's endpoint."""
    settings = rec.robots[0].settings
    if rec.placed:
        return open_session(settings.zenoh_endpoint, mode="client", credentials=None)
    if rec.own_router:
        router_args = ["-m", "hil.bench.router", settings.zenoh_endpoint, *rec.ids.router_args()]
        env = rec.ids.child_env("router")
        sup = rec.sup
        sup.start_python("router", router_args, env=env, stdout=logs.open("router"), stderr=STDOUT)
        _wait_port(settings.zenoh_endpoint, stop, 30.0)
        creds = rec.ids.credentials("recorder")
        return open_session(settings.zenoh_endpoint, mode="client", credentials=creds)
    return open_session(settings.zenoh_endpoint, listen_endpoint=True, credentials=None)


def start_services(
    sup: Supervisor,
    run_dirs: list[Path],
    ids: Any,
    logs: _Logs,
    host: HostSampler,
    placed: Any = None,
    log_prefix: str = "",
    roles: tuple[str, ...] = ("plant", "controller"),
) -> None:
    """The plant and controller processes of the run folders' robots (on their lab hosts when
    ``placed``), watched by the host sampler; their PIDs in processes.json (tests signal them)."""
    paths = [str(d / layout.RUN_SETTINGS) for d in run_dirs]
    modules = {"plant": "plant_emulator", "controller": "controller_service"}
    for name in roles:
        module = modules[name]
        child = sup.start(
            name,
            child_argv(placed, name, [sys.executable, "-m", module, *paths]),
            env=ids.child_env(name),
            stdout=logs.open(log_prefix + name),
            stderr=STDOUT,
        )
        host.pids[name] = child.pid
    pids = json.dumps({c.name: c.pid for c in sup.children})
    for d in run_dirs:
        (d / layout.PROCESSES).write_text(pids)


@dataclass
class RobotRun:
    """One robot of a recording: its folder as :func:`prepare` wrote it, and its recorder."""

    scenario: Scenario
    settings: RunSettings
    run_dir: Path
    design: LoopDesign
    recorder: Recorder

    @property
    def id(self) -> str:
        """The robot's id: its keys hil/<id>/..., as its services read it."""
        return self.settings.robot_id

    def recorded(self, extra: RunExtra) -> Recorded:
        """The raw run folder, with what the analysis needs to finish it."""
        ref, ctx = self.design.reference, self.design.context
        return Recorded(self.run_dir, self.scenario, self.settings, ref, ctx, extra)


#: What starts a recording's services and follows the run: (recording, the recorder's
#: session, the children's logs, the host sampler, the recording's resources to add to);
#: returns an error (or None) and how the controller process ended when it ended first.
Follow = Callable[
    ["Recording", Any, "_Logs", HostSampler, contextlib.ExitStack],
    tuple["RunError | None", ControllerExit | None],
]


@dataclass(frozen=True)
class RunError:
    """What stopped a run before it ran, in one sentence, and whose it is: the bench's own
    (its services never ready: summary.json's ``bench_error``, INCONCLUSIVE) or the system's
    (no outside device came: ``error``, FAIL)."""

    sentence: str
    bench: bool


@dataclass
class Recording:
    """One recording of K robots (``hil run``: K = 1; a fleet's group, K > 1): what they share
    (one Zenoh session, one supervisor, one host sampler, the children's logs) and, once
    :func:`record_robots` returned, how it ended."""

    robots: list[RobotRun]
    ids: RunIdentities
    logs_dir: Path  # the children's console logs (log_prefix + <name>.log)
    placed: Any = None  # on a lab's hosts (hil.bench.lab.placement)
    own_router: bool = False  # start the run's router (its settings' zenoh_mode "router")
    device: bool = False  # an outside device is the controller (the topology says so)
    group: bool = False  # a fleet's group: its robots share the processes (summary.json says)
    sup: Supervisor = dataclasses.field(default_factory=Supervisor)
    codes: dict[str, int | None] = dataclasses.field(default_factory=dict)
    error: RunError | None = None
    ended: ControllerExit | None = None
    wall_s: float = 0.0

    def extra(self, interrupted: bool, secure: bool = False) -> list[RunExtra]:
        """What each robot's summary.json says about the run itself (in this key order)."""
        out = []
        for r in self.robots:
            extra = run_extra(interrupted, self.error, self.wall_s, self.codes, r.recorder, secure)
            if self.group:
                extra["shared_processes"] = {
                    "robots": [x.id for x in self.robots],
                    "processes": ["plant", "controller"],
                }
            if self.ended is not None:  # every robot the process served lost its controller
                extra["controller_exit"] = self.ended
            out.append(extra)
        return out


def record_robots(rec: Recording, stop: Any, follow: Follow) -> None:
    """The one lifecycle of a recording: the recorder's session and each robot's keys into
    its own recording, then ``follow`` (which starts the services); on the way out, in this
    order, whatever happened: the services stopped by PID (their codes in ``rec.codes``),
    the host sampler, the logs, the identities, ``follow``'s own resources, the
    subscriptions, the session, then each robot's topology and recording (the hop logs
    attached)."""
    first = rec.robots[0]
    t0 = time.monotonic()
    with contextlib.ExitStack() as held:  # closed in the reverse order of their entry
        for r in rec.robots:
            held.callback(_close_recording, r, first.run_dir, rec.placed, rec.device)
        held.callback(rec.ids.close)
        logs = held.enter_context(_Logs(rec.logs_dir))
        host = HostSampler(first.run_dir)
        held.callback(host.close)
        with _services_stopped(rec):
            session = _open_recorder_session(rec, logs, stop)
            held.callback(session.close)
            for r in rec.robots:  # the robot's own keys only: robots may share the routers
                for key in observed_keys(r.id):
                    held.callback(session.declare_subscriber(key, r.recorder.on_zenoh).undeclare)
            rec.error, rec.ended = follow(rec, session, logs, host, held)
    rec.wall_s = time.monotonic() - t0


@contextlib.contextmanager
def _services_stopped(rec: Recording) -> Iterator[None]:
    """Every child of the recording stopped by its PID on the way out (their exit codes)."""
    try:
        yield
    finally:
        rec.codes = _stop_children(rec.sup, rec.robots[0].settings)


def _close_recording(r: RobotRun, first_dir: Path, placed: Any, device: bool) -> None:
    """A robot's folder completed (the shared host log, which host ran what), then its
    recording closed with the files it carries."""
    if r.run_dir != first_dir and (first_dir / layout.HOST_LOG).is_file():
        shutil.copyfile(first_dir / layout.HOST_LOG, r.run_dir / layout.HOST_LOG)
    placement.write_topology(placed, r.run_dir, device=device)  # before the recording takes it
    r.recorder.close(attachment_files(r.run_dir))


# A fleet's groups start on a grid: released together within the barrier's poll, they pick
# the same base (one host, one clock), so the robots' phases interleave across groups too.
START_GRID_NS = 500_000_000


def phase_ns(robot: str, position: int, n: int, period: int) -> int:
    """Robot I's epoch shift, (I - 1) / N of a period (I: from ``robotI``, else its position)."""
    m = re.fullmatch(r"robot(\d+)", robot)
    index = int(m.group(1)) - 1 if m else position
    return period * (index % n) // n if n > 0 else 0


def start_and_follow(
    rec: Recording,
    stop: Any,
    announcer: Any,
    quiet: bool,
    *,
    arrival: Any = None,
    conn: device.DeviceConnection | None = None,
    fleet_size: int | None = None,
    output: str = layout.CONTROLLER_OUTPUT,
) -> tuple[RunError | None, ControllerExit | None]:
    """Wait for every robot's services (an outside device: for the plant, then for the
    device, whose connection ``conn`` is said and saved in its folder), start them together
    with the rest of the fleet, follow the run; an error (or None) and how the controller
    ended when it ended before the plant (or None). ``fleet_size``: the robots' epochs
    interleaved (:func:`phase_ns`) on a grid shared by the fleet's groups; None: one epoch,
    now. ``output``: the controller's console log, relative to the run folder."""
    robots = rec.robots
    deadline = time.monotonic() + ready_timeout_s()  # a child that ends is noticed at once
    roles = {"plant"} if arrival is not None else {"plant", "controller"}
    for r in robots:
        left = max(0.0, deadline - time.monotonic())
        missing = _wait_ready(r.recorder, rec.sup, stop, left, roles)
        if missing is None:
            continue
        if missing.ended.get("controller") == LAW_FAULT_EXIT:  # its law could not be built
            return None, controller_exit(LAW_FAULT_EXIT, None, output)
        whose = f" of {r.id}" if len(robots) > 1 else ""
        logs = output.removesuffix(layout.CONTROLLER_OUTPUT)  # the children's logs are beside
        return RunError(missing.sentence(whose, logs), bench=True), None
    if arrival is not None and conn is not None:
        error = _wait_device(arrival, conn, rec.sup, stop, robots[0].run_dir)
        if error is not None:
            return error, None
    barrier = os.environ.get(fleet_barrier.ENV)
    if barrier:  # every robot of this recording is ready
        for r in robots:
            fleet_barrier.release(Path(barrier.rsplit(":", 2)[0]), r.id)
    fleet_barrier.wait(stop)  # a fleet's robots start together (no-op for one run)
    if fleet_size is None:
        base = time.monotonic_ns() + 300_000_000
        epochs = [base]
    else:
        base = -(-(time.monotonic_ns() + 300_000_000) // START_GRID_NS) * START_GRID_NS
        n = fleet_size or len(robots)
        periods = [period_ns(r.settings.ts) for r in robots]
        epochs = [base + phase_ns(r.id, i, n, periods[i]) for i, r in enumerate(robots)]
    for seq in range(3):  # a start message lost to a racing link must not hang
        for r, epoch in zip(robots, epochs, strict=True):
            announce_start(announcer, r.id, epoch, seq=seq)
        time.sleep(0.02)
    first = robots[0]
    return None, _progress(first.settings, first.recorder, rec.sup, stop, quiet, base, output)


def execute(opts: RunOptions) -> Recorded:
    """Run the pair and record it; the raw run folder written, what the analysis needs to
    finish it (:func:`hil.analysis.analyze.write_results`, which ``hil run`` calls next)."""
    # --lab: the recorder's lab host; [impair]: the run's own network namespace (either way
    # this command is executed again there).
    # the user's scenario file parsed once, when first needed (hil.scenario.load_scenario)
    load = functools.cache(lambda: load_scenario(resolve_scenario(opts.scenario)))
    impaired = bool(opts.lab) and impair.plan_of(opts, check_options, load) is not None
    placed = placement.enter(opts, impaired, impair.started_as_hil_run())
    impairment = None if placed else impair.enter(opts, check_options, load)
    scenario, settings, run_dir, design = prepare(opts, load)
    _say_start(opts, scenario, settings, run_dir)
    metadata = {"robot_id": settings.robot_id, "cmd_path": settings.cmd_path}
    metadata.update({"lockstep": settings.lockstep, "rate_hz": design.rate_hz})
    writer = RecordingWriter(run_dir / layout.RECORDING, metadata=metadata)
    recorder = Recorder(writer, same_clock=not placed)
    robot = RobotRun(scenario, settings, run_dir, design, recorder)
    external = opts.controller == "external"
    rec = Recording(
        [robot],
        RunIdentities(opts.secure, (settings.robot_id,)),  # fresh passwords, or none
        run_dir,
        placed,
        own_router=settings.zenoh_mode == "router",
        device=external,
    )

    def follow(rec: Recording, session: Any, logs: _Logs, host: HostSampler,
               held: contextlib.ExitStack) -> tuple[str | None, ControllerExit | None]:  # fmt: skip
        announcer = rec.ids.announcer(session, settings.zenoh_endpoint)
        lab = (placed.lab, placed.controller) if placed else None
        netns = os.getpid() if impairment is not None else None  # unshare exec'd: same PID
        conn = device.connection(settings, opts.wait_device, lab, netns) if external else None
        arrival = _arrival(settings, session) if external else None
        if arrival is not None:
            held.callback(arrival.close)
        also = arrival.on_frame if isinstance(arrival, device.CanArrival) else None
        can_rec = _can_recorder(settings, robot.recorder, also)
        if can_rec is not None:
            held.callback(_stop_can_recorder, can_rec, robot.recorder)
        if opts.live_port is not None:  # its own process: no cycle of the recorder's
            start_for_run(rec.sup, run_dir, opts.live_port, opts.live_host, logs, bool(placed))
        roles = ("plant",) if external else ("plant", "controller")
        start_services(rec.sup, [run_dir], rec.ids, logs, host, placed, roles=roles)
        return start_and_follow(rec, stop, announcer, opts.quiet, arrival=arrival, conn=conn)

    planned_end = False
    with stop_on_signals() as stop:
        try:
            record_robots(rec, stop, follow)
            # An open-ended run's stop is its end, not an interruption (once it has started).
            planned_end = opts.until_stopped and rec.error is None and bool(stop)
        finally:
            if stop and not planned_end:  # hil.cli then exits 130 once the folder is written
                interrupts.record(stop.signal or signal.SIGINT)
        interrupted = bool(stop) and not planned_end
    (extra,) = rec.extra(interrupted, opts.secure)
    if opts.until_stopped:
        extra["until_stopped"] = True
    extra.update(impair.finish(impairment, run_dir))  # the kernel's counts of what it dropped
    return robot.recorded(extra)


def _stop_can_recorder(can_rec: tuple[Any, Any, Any], recorder: Recorder) -> None:
    """The CAN recording's notifier stopped and its bus shut down; the frames its own socket
    dropped (its queue full) counted: the recording's loss, the bench's, never the system's."""
    bus, notifier, drops = can_rec
    notifier.stop()
    recorder.can_socket_drops = drops.read()
    drops.close()
    with contextlib.suppress(Exception):  # a bus already gone is fine here
        bus.shutdown()


def run_extra(
    interrupted: bool,
    error: RunError | None,
    wall: float,
    codes: Any,
    recorder: Recorder,
    secure: bool,
) -> RunExtra:
    """What ``hil run`` adds to summary.json about the run itself (in this key order)."""
    return {
        "interrupted": interrupted,
        "error": error.sentence if error is not None and not error.bench else None,
        "bench_error": error.sentence if error is not None and error.bench else None,
        "wall_time_s": wall,
        "exit_codes": codes,
        "recording": layout.RECORDING,
        "recorded_messages": recorder.writer.count,
        "recorder": {
            **recorder.taps.counts(),
            "can_frames_dropped_by_socket": recorder.can_socket_drops,
        },
        "secure": secure,
    }


# The clock exchanges and, on a lab, which host ran what (hil.bench.lab.placement).
ATTACHED = (layout.CONTROLLER_LOG, layout.PLANT_LOG, layout.HOST_LOG, layout.SCENARIO_RESOLVED)
ATTACHED += (layout.CLOCK, layout.TOPOLOGY)


def attachment_files(run_dir: Path) -> dict[str, Path]:
    """The files a recording carries (so that it alone reproduces the figures), by path."""
    return {name: run_dir / name for name in ATTACHED if (run_dir / name).is_file()}


class _Logs(contextlib.ExitStack):
    """The children's console logs (``<name>.log`` in the run folder), closed at the end."""

    def __init__(self, run_dir: Path) -> None:
        super().__init__()
        self.run_dir = run_dir

    def open(self, name: str) -> Any:
        return self.enter_context((self.run_dir / f"{name}.log").open("wb"))


def _wait_port(endpoint: str, stop: Any, timeout: float) -> bool:
    """Until something accepts TCP connections on the endpoint's port (the router is up)."""
    host, _, port = endpoint.split("/", 1)[1].rpartition(":")
    deadline = time.monotonic() + timeout
    while not stop and time.monotonic() < deadline:
        with contextlib.suppress(OSError), socket.create_connection((host, int(port)), 0.2):
            return True
        time.sleep(0.02)
    return False


def _say_start(opts: RunOptions, scenario: Any, settings: RunSettings, run_dir: Path) -> None:
    """The run's start line (hil.ticker): what runs, for how long, where it writes."""
    name = Path(opts.scenario).name if opts.scenario else "paper_tracking (default)"
    law = scenario.controller.get("law", "unified")
    if opts.controller == "external":
        law = "your device (--controller external)"
    what = f"{name}, law {law}, {1 / settings.ts:g} Hz, commands on {settings.cmd_path}"
    length = "until Ctrl-C" if opts.until_stopped else f"{settings.duration:g} s"
    ticker.start_line("run", what, length, run_dir)


def _arrival(settings: RunSettings, session: Any) -> device.ZenohArrival | device.CanArrival:
    """What shows that the run's outside device is there, on its path."""
    if settings.cmd_path == "can":
        return device.CanArrival((int(settings.can["node_left"]), int(settings.can["node_right"])))
    return device.ZenohArrival(session, state_key(settings.robot_id))


def _wait_device(
    arrival: Any, conn: device.DeviceConnection, sup: Supervisor, stop: Any, run_dir: Path
) -> RunError | None:
    """Say how the device connects (stderr and device.json), wait for it; None once it is
    there, else why the run cannot start (a FAIL of the device's: it never came; the bench's
    when its plant ended meanwhile)."""
    conn.save(run_dir)
    for line in conn.lines():
        ticker.say(line)
    how, waited = device.wait(
        arrival, stop, conn.wait_s, lambda: all(c.alive() for c in sup.children)
    )
    if how is None:
        if stop or not all(c.alive() for c in sup.children):
            ended = "the bench did not start the run: its plant ended while waiting for the device"
            return None if stop else RunError(ended, bench=True)
        where = conn.zenoh.endpoint if conn.zenoh else (conn.can.channel if conn.can else "")
        said = f"no device connected within {conn.wait_s:g} s: {arrival.nobody(where)}"
        return RunError(said, bench=False)
    dataclasses.replace(conn, connected_after_s=round(waited, 3), how=how).save(run_dir)
    ticker.say(f"device connected after {waited:.1f} s ({how}); the run starts")
    return None


@dataclass(frozen=True)
class NotReady:
    """Services that did not say "ready": ``missing`` their roles, ``ended`` the exit codes of
    the children that ended meanwhile (by name), ``waited_s``; ``stopped``: a stop was asked."""

    missing: tuple[str, ...]
    ended: dict[str, int | None]
    waited_s: float
    stopped: bool

    def sentence(self, whose: str = "", logs: str = "") -> str:
        """Why the bench did not start the run (``logs``: where the children's console logs
        are, relative to the run folder)."""
        head = f"the bench did not start the run{whose}"
        if self.stopped:
            return f"{head}: stopped while its services started"
        if self.ended:
            name, code = next(iter(self.ended.items()))
            return (
                f"{head}: the {name} exited with code {code} before it was ready (its output: "
                f"{logs}{name}.log)"
            )
        names = " and the ".join(self.missing)
        outputs = ", ".join(f"{logs}{m}.log" for m in self.missing)
        return (
            f"{head}: the {names} did not say ready within {self.waited_s:.3g} s (still "
            f"starting: a host too slow or too busy; output: {outputs})"
        )


def _wait_ready(
    recorder: Recorder,
    sup: Supervisor,
    stop: Any,
    timeout: float,
    roles: set[str] | frozenset[str] = frozenset({"plant", "controller"}),
) -> NotReady | None:
    """Until each of ``roles`` said "ready" (None), a child ended, the timeout, or a stop."""
    t0 = time.monotonic()
    while True:
        ready = {r for r, m in recorder.statuses.items() if m.state == "ready"}
        if roles <= ready:
            return None
        ended = {c.name: c.proc.poll() for c in sup.children if not c.alive()}
        if stop or ended or time.monotonic() - t0 >= timeout:
            missing = tuple(sorted(roles - ready, key=("plant", "controller").index))
            return NotReady(missing, ended, time.monotonic() - t0, bool(stop))
        time.sleep(0.02)


def _progress(
    settings: RunSettings,
    recorder: Recorder,
    sup: Supervisor,
    stop: Any,
    quiet: bool,
    epoch_ns: int,
    output: str = layout.CONTROLLER_OUTPUT,
) -> ControllerExit | None:
    """Until the plant finishes its duration (it exits by itself), a stop is asked, or the
    controller process ended first: at once when its law failed (it exits with
    LAW_FAULT_EXIT: no command will come any more), else (a crash, a signal) after
    GONE_GRACE_S unless a restarted controller rejoins meanwhile (its Status says
    ``restarted``: then the run goes on to its end). The plant is stopped next, by
    _stop_children. That end is returned (its code or signal, and when: from ``epoch_ns``,
    within the 50 ms of a poll; ``output``: its console log, relative to the run folder)."""
    total = max(1, round(settings.duration / settings.ts)) if settings.lockstep else None
    plant = next(c for c in sup.children if c.name == "plant")
    controller = next((c for c in sup.children if c.name == "controller"), None)
    gone_ns: int | None = None  # when the controller process was found ended
    t0 = time.monotonic()
    limit = t0 + (settings.duration + 30.0 if not settings.lockstep else 1e9)
    with Progress(
        TextColumn("hil run"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TextColumn("{task.fields[info]}"),
        TimeElapsedColumn(),
        transient=True,
        disable=quiet or not sys.stderr.isatty(),  # then only the wait
    ) as prog:
        task = prog.add_task("run", total=1.0, info="")
        tick = ticker.Ticker("hil run", enabled=not quiet and not sys.stderr.isatty())
        while not stop and plant.alive() and time.monotonic() < limit:
            if controller is not None and gone_ns is None and not controller.alive():
                gone_ns = time.monotonic_ns()
            if gone_ns is not None and _stop_now(controller, recorder, gone_ns):
                break
            st = recorder.statuses.get("controller")
            info = ""
            if st is not None:
                c = st.counters
                info = f"cycles {c.get('cycles', 0)} misses {c.get('deadline_misses', 0)}"
            done = recorder.states / total if total else (time.monotonic() - t0) / settings.duration
            prog.update(task, completed=min(1.0, done), info=info)
            elapsed = time.monotonic() - t0
            tick.tick(f"{elapsed:.0f} s of {settings.duration:g} s" + (f", {info}" if info else ""))
            time.sleep(0.05)
    if not quiet:  # the phases after the run take seconds on a long one
        ticker.say("hil run: the run ended; stopping the services, then measuring and judging")
    # The controller outlives the plant (its end is 2 s past the plant's) until it is stopped:
    # found ended here, it ended on its own, before the run's end.
    if controller is None or controller.alive():
        return None
    gone_ns = gone_ns or time.monotonic_ns()
    return controller_exit(controller.proc.poll(), (gone_ns - epoch_ns) / 1e9, output)


# After the controller process died of something else than its law (a crash, a signal), the
# plant runs on this long: its own safe state shows (the command timeout's zero torque, the
# drives' watchdog: about a second), and a controller restarted into the run by hand or by a
# supervisor rejoins (a Python process with numpy and Zenoh starts in 1-3 s on a loaded 2-core
# host; bench/kill_matrix.py's controller_restart). Then the run stops: it does not wait out
# its duration.
GONE_GRACE_S = 3.0


def _stop_now(controller: Any, recorder: Recorder, gone_ns: int) -> bool:
    """Whether to end the run now that the controller process ended at ``gone_ns``."""
    if controller.proc.poll() == LAW_FAULT_EXIT:
        return True  # its law failed: it will not come back
    status, seen = recorder.statuses.get("controller"), recorder.status_ns.get("controller", 0)
    if status is not None and seen > gone_ns and status.counters.get("restarted"):
        return False  # a restarted controller rejoined the run: follow it to the end
    return time.monotonic_ns() - gone_ns > GONE_GRACE_S * 1e9


def controller_exit(code: int | None, t_s: float, output: str) -> ControllerExit:
    """summary.json's ``controller_exit`` from the process's return code (negative: the
    signal that killed it; hil.folder.records.ControllerExit)."""
    sig = None
    if code is not None and code < 0:
        try:
            sig = signal.Signals(-code).name
        except ValueError:
            sig = f"signal {-code}"
    return {
        "code": None if sig else code,
        "signal": sig,
        "t_s": t_s,
        "law_fault": code == LAW_FAULT_EXIT,
        "output": output,
    }


def _stop_children(sup: Supervisor, settings: RunSettings) -> dict[str, int | None]:
    codes: dict[str, int | None] = {}
    # The plant ends by itself at the run's end; the controller is stopped next, then the rest.
    for name in ("plant", "controller", "router", "live"):
        for c in [c for c in sup.children if c.name == name]:
            if name == "controller" and codes.get("plant") not in (0, None) and c.alive():
                # The plant died: give the controller's stale-state watchdog time to act (and
                # to be logged) before it is stopped.
                time.sleep(max(0.2, 4 * settings.state_timeout))
            codes[name] = c.stop(grace=10.0)
    return codes

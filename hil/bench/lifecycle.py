"""``hil run``: start the pair (and a router if asked), record everything, write the folder.

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
import random
import signal
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from subprocess import STDOUT
from typing import Any

import can
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from hil import interrupts, options, ticker
from hil.bench import device, impair
from hil.bench.defaults import PAPER_TRACKING_TOML
from hil.bench.fleet import barrier as fleet_barrier
from hil.bench.host_load import HostSampler
from hil.bench.lab import placement
from hil.bench.lab.placement import child_argv
from hil.bench.live.launch import check as live_check
from hil.bench.live.launch import start_for_run
from hil.bench.recorder import Recorder, RecordingWriter
from hil.bench.secure import RunIdentities
from hil.bench.settings import (
    check_can_interface,
    effective_can_table,
    replay_latencies,
    scenario_settings,
)
from hil.bench.supervisor import Supervisor
from hil.bundled import resolve_scenario
from hil.errors import BadInputError
from hil.folder import claim, layout, new_run_dir
from hil.folder.records import ControllerExit, Recorded, RunExtra
from hil.folder.replay import RunLatencies
from hil.law.option import with_law
from hil.provenance import dumps_toml
from hil.scenario import (
    DURATION_MAX,
    MAX_SAMPLES,
    RATE_MAX,
    Scenario,
    build_loop,
    load_scenario,
    loads_scenario,
    resolved_dict,
)
from protocol.can.rx_queue import RxQueueDrops
from protocol.hoplog import LAW_FAULT_EXIT
from protocol.keys import is_valid_robot_id, observed_keys, state_key
from protocol.settings import CMD_PATHS, SCHEDULING, TRIGGERS, RunSettings, period_s
from runtime.signals import stop_on_signals
from runtime.startgate import announce_start
from runtime.zsession import open_session

LAB_ROUTER = "tcp/127.0.0.1:7447"  # a lab host's own router, from inside the host (hil.bench.lab)


# Ports the kernel never hands out on its own (below Linux's ephemeral range, 32768-60999): a
# port from that range, free when picked, was seen taken by another process's ephemeral
# listener or connection before the run's own listen (16 runs of a fleet at once).
PORTS = (20000, 32000)


def _endpoint(opts: RunOptions) -> str:
    """The run's Zenoh endpoint: the one given (a campaign keeps its device's), else free."""
    return opts.zenoh_endpoint or f"tcp/127.0.0.1:{free_port()}"


def free_port() -> int:
    """A loopback TCP port nothing listens on now, outside the ephemeral range."""
    for _ in range(200):
        port = random.randrange(*PORTS)
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class RunOptions:
    scenario: Path | None = None
    duration: float | None = None
    rate: float | None = None
    cmd_path: str = "zenoh"
    lockstep: bool = False
    out: Path | None = None
    trigger: str | None = None
    can_live: bool = True
    can_interface: str | None = None
    can_channel: str | None = None
    spin_us: float = 0.0
    scheduling: str | None = None
    quiet: bool = False
    secure: bool = False  # router with authentication and access control (hil.bench.secure)
    live_port: int | None = None  # serve the run live (hil.bench.live) on this port; None: no
    live_host: str = "127.0.0.1"
    law: str | None = None  # --law: the [controller] law instead of the scenario's
    lab: str | None = None  # run on a lab's hosts (hil.bench.lab.placement)
    plant_host: str | None = None
    controller_host: str | None = None
    robot_id: str | None = None  # instead of the scenario's (hil fleet: one per robot)
    force: bool = False  # --force: replace a folder that holds files (hil.folder.claim)
    # False: hil controller / hil emulator, two services that share one folder (default ".")
    fresh_out: bool = True
    # "external": no controller of the bench's; an outside device (hil.bench.device)
    controller: str = "bench"
    wait_device: float = device.WAIT_DEVICE_S  # s an outside device is waited for
    zenoh_endpoint: str | None = None  # the run's Zenoh endpoint; None: a free loopback port
    can_endpoint: str | None = None  # the zenoh_can bus's endpoint; None: a free loopback port
    # --until-stopped: no duration; Ctrl-C (SIGINT/SIGTERM) is the run's planned end
    until_stopped: bool = False
    # [timing] replay naming a real run: the reader of its latencies (the analysis's,
    # hil.analysis.replay.latencies_from_run, handed over by the command); None: files only
    run_latencies: RunLatencies | None = None


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


SPIN_US_MAX = 1e6


def check_options(opts: RunOptions) -> None:
    """``hil run``'s options (also a service's alone), each named in a BadInputError."""
    options.choice("--cmd-path", opts.cmd_path, CMD_PATHS)
    if opts.trigger is not None:
        options.choice("--trigger", opts.trigger, TRIGGERS)
    if opts.scheduling is not None:
        options.choice("--scheduling", opts.scheduling, SCHEDULING)
    options.optional_number("--rate", opts.rate, 0.1, RATE_MAX)
    options.optional_number("--duration", opts.duration, 0.0, DURATION_MAX, positive=True)
    options.number("--spin-us", opts.spin_us, 0.0, SPIN_US_MAX)
    if opts.can_interface is not None:
        options.plain_string("--can-interface", opts.can_interface, empty=False)
    if opts.can_channel is not None:
        options.plain_string("--can-channel", opts.can_channel, empty=False)
    if opts.fresh_out:
        claim.check("--out", opts.out, opts.force, default="runs")
    else:
        options.out_dir("--out", opts.out, default="runs")
    if opts.robot_id is not None and not is_valid_robot_id(opts.robot_id):
        raise BadInputError(f"--robot-id {opts.robot_id!r}: 1-64 characters of [A-Za-z0-9_.-]")
    live_check(opts.live_port, opts.live_host)
    if opts.live_port is not None and opts.secure:
        raise BadInputError("--live does not log in to a --secure run's router")
    _check_device_options(opts)


def _check_device_options(opts: RunOptions) -> None:
    """--controller, --wait-device, --zenoh-endpoint, and what an outside device excludes."""
    options.choice("--controller", opts.controller, device.CONTROLLERS)
    options.number("--wait-device", opts.wait_device, 0.0, DURATION_MAX, positive=True)
    for name, endpoint in (
        ("--zenoh-endpoint", opts.zenoh_endpoint),
        ("--can-endpoint", opts.can_endpoint),
    ):
        if endpoint is not None:
            device.check_endpoint(name, endpoint)
    if opts.until_stopped and opts.duration is not None:
        raise BadInputError("--until-stopped runs until Ctrl-C: it takes no --duration")
    if opts.controller != "external":
        if opts.until_stopped:
            raise BadInputError("--until-stopped is for --controller external (a device's session)")
        return
    for given, name in (
        (opts.lockstep, "--lockstep (the plant would wait for each command in turn)"),
        (opts.secure, "--secure (the device would need the run's passwords)"),
        (opts.law, "--law (the device is the law)"),
    ):
        if given:
            raise BadInputError(f"--controller external does not take {name}")


def _control_rate(opts: RunOptions, scenario: Any) -> tuple[float, str]:
    """The control rate (Hz) and the name of what set it ("" for the scenario's own Ts)."""
    if opts.rate is not None:
        return opts.rate, "--rate"
    if scenario.realtime.rate:
        return scenario.realtime.rate, "[realtime] rate"
    rate = 1.0 / scenario.timing.ts
    if rate > RATE_MAX:
        raise BadInputError(
            f"[timing] ts = {scenario.timing.ts:g} s is a control rate of {rate:g} Hz, above "
            f"the {RATE_MAX:g} Hz hil run supports (set [realtime] rate or --rate)"
        )
    return rate, ""


def _run_settings(
    opts: RunOptions, scenario: Any, context: Any, scenario_path: Path, run_dir: Path, rate: float
) -> RunSettings:
    """The settings both services read (:class:`protocol.settings.RunSettings`)."""
    rt = scenario.realtime
    ts_s = scenario.timing.ts  # already 1 / rate when a rate overrode it (prepare)
    sensor_rate = rate if opts.lockstep else (rt.sensor_rate or rate)
    can_table = effective_can_table(scenario, opts.can_interface)  # with the command line's
    if opts.can_channel:
        can_table["channel"] = opts.can_channel
    if (opts.can_live and opts.controller != "external") or opts.cmd_path == "can":
        where = "--can-interface" if opts.can_interface else "[can] interface"
        check_can_interface(can_table["interface"], where)
    settings = scenario_settings(
        scenario,
        context,
        scenario_path=str(scenario_path),
        epoch_ns=0,
        # The scenario's Ts bit for bit when no rate overrides it (1 / (1 / ts) may differ in
        # the last bit, and lockstep must see the simulator's sample times exactly).
        ts=ts_s,
        sensor_ts=ts_s if sensor_rate == rate else period_s(sensor_rate),
        trigger=opts.trigger or rt.trigger,
        lockstep=opts.lockstep,
        # Lockstep is about values, not timing; and a SCHED_FIFO main thread there was seen to
        # starve Zenoh's helper threads (seconds-long stalls with the CAN path live).
        scheduling="other" if opts.lockstep else (opts.scheduling or rt.scheduling),
        cmd_path=opts.cmd_path,
        can_live=opts.can_live,
        can=can_table,
        # On a lab, each process is a client of its own host's router (hil.bench.lab.placement).
        zenoh_mode="router" if opts.secure or opts.lab else scenario.zenoh.mode,
        zenoh_endpoint=LAB_ROUTER if opts.lab else _endpoint(opts),
        can_endpoint=opts.can_endpoint or f"tcp/127.0.0.1:{free_port()}",
        delay=scenario.timing.delay,
        out_dir=str(run_dir.resolve()),
        spin_us=opts.spin_us,
        replay=replay_latencies(scenario, opts.run_latencies),
    )
    if opts.robot_id is not None:
        settings.robot_id = opts.robot_id
    if opts.controller == "external":
        # The plant waits for its start while the device is waited for.
        settings.start_timeout = max(settings.start_timeout, opts.wait_device + 60.0)
        if opts.cmd_path == "zenoh":
            settings.can_live = False  # nobody would drive the CAN shadow
    if (os.cpu_count() or 1) >= 2:
        settings.cpu_controller, settings.cpu_plant = 1, 0
    settings.validate()
    return settings


def prepare(
    opts: RunOptions, load: Callable[[], Scenario] | None = None
) -> tuple[Any, RunSettings, Path, dict[str, Any]]:
    """Resolve the scenario (``load``: the user's file, parsed once) and the run's settings;
    write the folder's first files."""
    check_options(opts)  # every option before the scenario: no folder, no process yet
    if opts.secure and opts.cmd_path == "can":
        raise BadInputError("--secure guards the Zenoh command path; the CAN bus has no login")
    if opts.lockstep and opts.cmd_path == "can":
        # The lockstep plant waits for the Zenoh command computed from each State (docs/
        # realtime.md, "Lockstep"): a CAN applied path would never land a command.
        raise BadInputError(
            "--lockstep exchanges each State and its command on Zenoh: --cmd-path can is not "
            "supported with it (the CAN path still runs beside it as a shadow)"
        )
    run_dir = Path(opts.out) if opts.out else new_run_dir()
    given = None if opts.scenario is None else resolve_scenario(opts.scenario)  # file or name
    if given is None:  # the paper's tracking circle, written into the folder
        scenario = with_law(loads_scenario(PAPER_TRACKING_TOML, run_dir), opts.law)
        scenario_path = run_dir / layout.SCENARIO
    else:
        scenario = with_law(load() if load is not None else load_scenario(given), opts.law)
        scenario_path = given.resolve()
    rate, rate_name = _control_rate(opts, scenario)
    duration = opts.duration if opts.duration is not None else scenario.run.duration
    if opts.until_stopped:  # until Ctrl-C, at most the longest loop a scenario may ask
        duration = min(DURATION_MAX, (MAX_SAMPLES - 1) / rate)
    scenario = scenario.with_overrides(
        duration=duration,
        ts=scenario.timing.ts if not rate_name else period_s(rate),
        names=(
            "--duration" if opts.duration is not None else "[run] duration",
            f"1 / {rate_name}" if rate_name else "[timing] ts",
        ),
    )
    controller, reference, context = build_loop(scenario)
    settings = _run_settings(opts, scenario, context, scenario_path, run_dir, rate)
    if opts.fresh_out:
        claim.take(run_dir, "run")
    run_dir.mkdir(parents=True, exist_ok=True)
    if given is None:
        scenario_path.write_text(PAPER_TRACKING_TOML)
    settings.save(run_dir / layout.RUN_SETTINGS)
    run_facts = {
        "command": "hil run",
        "cmd_path": settings.cmd_path,
        "lockstep": settings.lockstep,
        "rate_hz": float(rate),
        "trigger": settings.trigger,
        "can_interface": settings.can["interface"],
        "secure": opts.secure,
        "controller": opts.controller,
    }
    resolved = resolved_dict(scenario, controller, context, run_facts)
    (run_dir / layout.SCENARIO_RESOLVED).write_text(dumps_toml(resolved))
    info = {"reference": reference, "context": context, "rate_hz": float(rate)}
    return scenario, settings, run_dir, info


def _open_recorder_session(
    settings: RunSettings, ids: Any, sup: Supervisor, logs: _Logs, stop: Any, lab: bool = False
) -> Any:
    """The recorder's Zenoh session: on the run's endpoint, or a router's client (started
    here) in router mode, or the client of the lab host's own router."""
    if lab:
        return open_session(settings.zenoh_endpoint, mode="client", credentials=None)
    if settings.zenoh_mode == "router":
        router_args = ["-m", "hil.bench.router", settings.zenoh_endpoint, *ids.router_args()]
        env = ids.child_env("router")
        sup.start_python("router", router_args, env=env, stdout=logs.open("router"), stderr=STDOUT)
        _wait_port(settings.zenoh_endpoint, stop, 30.0)
        creds = ids.credentials("recorder")
        return open_session(settings.zenoh_endpoint, mode="client", credentials=creds)
    return open_session(settings.zenoh_endpoint, listen_endpoint=True, credentials=None)


def _start_services(
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


def _start_and_follow(
    settings: RunSettings,
    recorder: Recorder,
    sup: Supervisor,
    stop: Any,
    announcer: Any,
    quiet: bool,
    arrival: Any = None,
    conn: device.DeviceConnection | None = None,
    run_dir: Path | None = None,
) -> tuple[str | None, ControllerExit | None]:
    """Wait for both services (an outside device: for the plant, then for the device, whose
    connection ``conn`` is said and saved in ``run_dir``), announce the epoch, follow the
    run; an error (or None) and how the controller ended when it ended before the plant (or
    None)."""
    # Generous: start-up is seconds natively but minutes in an emulated (TCG) guest; a child
    # that dies is noticed at once anyway.
    ready_timeout = float(os.environ.get("HIL_READY_TIMEOUT", "300"))
    roles = {"plant"} if arrival is not None else {"plant", "controller"}
    if not _wait_ready(recorder, sup, stop, timeout=ready_timeout, roles=roles):
        return "services did not become ready", None
    if arrival is not None and conn is not None and run_dir is not None:
        error = _wait_device(arrival, conn, sup, stop, run_dir)
        if error is not None:
            return error, None
    fleet_barrier.wait(stop)  # a fleet's robots start together (no-op for one run)
    epoch = time.monotonic_ns() + 300_000_000
    for i in range(3):  # a start message lost to a racing link must not hang
        announce_start(announcer, settings.robot_id, epoch, seq=i)
        time.sleep(0.02)
    return None, _progress(settings, recorder, sup, stop, quiet, epoch)


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
    scenario, settings, run_dir, info = prepare(opts, load)
    _say_start(opts, scenario, settings, run_dir)
    sup = Supervisor()
    metadata = {"robot_id": settings.robot_id, "cmd_path": settings.cmd_path}
    metadata.update({"lockstep": settings.lockstep, "rate_hz": info["rate_hz"]})
    writer = RecordingWriter(run_dir / layout.RECORDING, metadata=metadata)
    recorder = Recorder(writer, same_clock=not placed)
    session, subs, can_rec, ended, arrival = None, [], None, None, None
    planned_end = False
    logs = _Logs(run_dir)
    t_start = time.monotonic()
    ids = RunIdentities(opts.secure, (settings.robot_id,))  # fresh passwords, or none
    host = HostSampler(run_dir)
    with stop_on_signals() as stop:
        try:
            session = _open_recorder_session(settings, ids, sup, logs, stop, bool(placed))
            announcer = ids.announcer(session, settings.zenoh_endpoint)
            # The run's own robot only: a fleet's robots may share the routers.
            subs = [
                session.declare_subscriber(key, recorder.on_zenoh)
                for key in observed_keys(settings.robot_id)
            ]
            external = opts.controller == "external"
            lab = (placed.lab, placed.controller) if placed else None
            netns = os.getpid() if impairment is not None else None  # unshare exec'd: same PID
            conn = device.connection(settings, opts.wait_device, lab, netns) if external else None
            arrival = _arrival(settings, session) if external else None
            also = arrival.on_frame if isinstance(arrival, device.CanArrival) else None
            can_rec = _can_recorder(settings, recorder, also)
            if opts.live_port is not None:  # its own process: no cycle of the recorder's
                start_for_run(sup, run_dir, opts.live_port, opts.live_host, logs, bool(placed))
            roles = ("plant",) if external else ("plant", "controller")
            _start_services(sup, [run_dir], ids, logs, host, placed, roles=roles)
            error, ended = _start_and_follow(
                settings, recorder, sup, stop, announcer, opts.quiet, arrival, conn, run_dir
            )
            # An open-ended run's stop is its end, not an interruption (once it has started).
            planned_end = opts.until_stopped and error is None and bool(stop)
            interrupted = bool(stop) and not planned_end
        finally:
            if stop and not planned_end:  # hil.cli then exits 130 once the folder is written
                interrupts.record(stop.signal or signal.SIGINT)
            codes = _stop_children(sup, settings)
            host.close()
            ids.close()
            logs.close()
            # before the recording takes it along
            placement.write_topology(placed, run_dir, device=opts.controller == "external")
            for sub in subs:
                sub.undeclare()
            if can_rec is not None:
                can_rec[1].stop()
                # Frames the recorder's own socket dropped (its queue full): the recording's
                # loss, the bench's, never the system's.
                recorder.can_socket_drops = can_rec[2].read()
                can_rec[2].close()
                with contextlib.suppress(Exception):  # a bus already gone is fine here
                    can_rec[0].shutdown()
            if arrival is not None:
                arrival.close()
            if session is not None:
                session.close()
            recorder.close(attachment_files(run_dir))  # the hop logs attached
    extra = run_extra(interrupted, error, time.monotonic() - t_start, codes, recorder, opts.secure)
    if ended is not None:
        extra["controller_exit"] = ended
    if opts.until_stopped:
        extra["until_stopped"] = True
    extra.update(impair.finish(impairment, run_dir))  # the kernel's counts of what it dropped
    return Recorded(run_dir, scenario, settings, info["reference"], info["context"], extra)


def run_extra(
    interrupted: bool, error: str | None, wall: float, codes: Any, recorder: Recorder, secure: bool
) -> RunExtra:
    """What ``hil run`` adds to summary.json about the run itself (in this key order)."""
    return {
        "interrupted": interrupted,
        "error": error,
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
) -> str | None:
    """Say how the device connects (stderr and device.json), wait for it; None once it is
    there, else why the run cannot start (a FAIL of the device's: it never came)."""
    conn.save(run_dir)
    for line in conn.lines():
        ticker.say(line)
    how, waited = device.wait(
        arrival, stop, conn.wait_s, lambda: all(c.alive() for c in sup.children)
    )
    if how is None:
        if stop or not all(c.alive() for c in sup.children):
            return None if stop else "the plant ended while the device was waited for"
        where = conn.zenoh.endpoint if conn.zenoh else (conn.can.channel if conn.can else "")
        return f"no device connected within {conn.wait_s:g} s: {arrival.nobody(where)}"
    dataclasses.replace(conn, connected_after_s=round(waited, 3), how=how).save(run_dir)
    ticker.say(f"device connected after {waited:.1f} s ({how}); the run starts")
    return None


def _wait_ready(
    recorder: Recorder,
    sup: Supervisor,
    stop: Any,
    timeout: float,
    roles: set[str] | frozenset[str] = frozenset({"plant", "controller"}),
) -> bool:
    deadline = time.monotonic() + timeout
    while not stop and time.monotonic() < deadline:
        ready = {r for r, m in recorder.statuses.items() if m.state == "ready"}
        if roles <= ready:
            return True
        if not all(c.alive() for c in sup.children):
            return False
        time.sleep(0.02)
    return False


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

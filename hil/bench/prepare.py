"""``hil run``'s options and the run folder's first files: the options checked (each named in
a BadInputError, before any folder or process), the scenario resolved with the command line's
overrides, the settings both services read (``run_settings.json``) and the resolved scenario
written. :mod:`hil.bench.lifecycle` then records the run in that folder.
"""

from __future__ import annotations

import dataclasses
import os
import random
import socket
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controller_service.laws.base import DesignContext
from hil import options
from hil.bench import device
from hil.bench.defaults import PAPER_TRACKING_TOML, ready_timeout_s
from hil.bench.live.launch import check as live_check
from hil.bench.settings import (
    check_can_interface,
    effective_can_table,
    replay_latencies,
    scenario_settings,
)
from hil.bundled import resolve_scenario
from hil.errors import BadInputError
from hil.folder import claim, layout, new_run_dir
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
from protocol.keys import is_valid_robot_id
from protocol.settings import CMD_PATHS, SCHEDULING, TRIGGERS, RunSettings, period_s

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


@dataclass(frozen=True)
class LoopDesign:
    """What :func:`prepare` derived from the scenario beside the run's settings: the
    reference (3) and the design context the analysis judges with, and the control rate."""

    reference: Any  # controller_service.reference's trajectory of the scenario
    context: DesignContext
    rate_hz: float


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

    def fleet_robot(self, robot: str | None, fleet_out: Path) -> RunOptions:
        """A fleet robot's ``hil run``: its robot id and folder FLEET_OUT/robot (None: the
        fleet's options, no robot's), quiet, no CAN shadow."""
        out = None if robot is None else fleet_out / robot
        return dataclasses.replace(self, robot_id=robot, out=out, quiet=True, can_live=False)

    def argv(self) -> list[str]:
        """``hil run``'s arguments for these options (what ``hil.commands.run.run_options``
        reads back): the scenario, then each field that differs from its default under its
        option; a field ``hil run`` has no option for must be at its default."""
        args = [] if self.scenario is None else [str(self.scenario)]
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "scenario" or value == f.default:
                continue
            if f.name in _NOT_OPTIONS:
                raise ValueError(f"hil run has no option for {f.name} = {value!r}")
            flag = "--" + _OPTION_OF_FIELD.get(f.name, f.name).replace("_", "-")
            if isinstance(value, bool):
                args.append(flag if value else "--no-" + flag[2:])
            else:
                args += [flag, repr(value) if isinstance(value, float) else str(value)]
        return args

    def to_json(self) -> dict[str, JsonValue]:
        """The options as JSON values (a fleet's group spec). The latencies reader is not
        one: each process that needs it is handed its own."""
        if self.run_latencies is not None:
            raise ValueError("run_latencies is a reader, not a value: hand it over instead")
        out: dict[str, JsonValue] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name != "run_latencies":
                out[f.name] = str(value) if isinstance(value, Path) else value
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, JsonValue]) -> RunOptions:
        """The options :meth:`to_json` wrote."""
        opts = cls(**data)  # type: ignore[arg-type]
        for name in ("scenario", "out"):
            if getattr(opts, name) is not None:
                setattr(opts, name, Path(str(getattr(opts, name))))
        return opts


JsonValue = str | float | int | bool | None

#: ``hil run``'s options whose RunOptions field is named otherwise; the rest share theirs.
FIELD_OF_OPTION = {"can": "can_live", "live": "live_port"}
_OPTION_OF_FIELD = {field: option for option, field in FIELD_OF_OPTION.items()}
#: RunOptions' fields ``hil run`` has no option for: set by the bench, never by a user.
_NOT_OPTIONS = ("scheduling", "fresh_out", "run_latencies")


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
    # Each service waits for its start while the other starts (hil run waits that long for
    # both to be ready), and while an outside device is waited for.
    waited = ready_timeout_s() + (opts.wait_device if opts.controller == "external" else 0.0)
    settings.start_timeout = max(settings.start_timeout, waited + 60.0)
    if opts.controller == "external" and opts.cmd_path == "zenoh":
        settings.can_live = False  # nobody would drive the CAN shadow
    if (os.cpu_count() or 1) >= 2:
        settings.cpu_controller, settings.cpu_plant = 1, 0
    settings.validate()
    return settings


def prepare(
    opts: RunOptions, load: Callable[[], Scenario] | None = None
) -> tuple[Scenario, RunSettings, Path, LoopDesign]:
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
    return scenario, settings, run_dir, LoopDesign(reference, context, float(rate))

"""``hil drives``: the plant and its two virtual ODrives on a CAN bus, until Ctrl-C: recorded
into a run folder, or free running with ``--no-record`` (the light form)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from hil.commands import ForceOpt, app
from hil.commands.run import LiveHostOpt, live_opt
from hil.errors import BadInputError

if TYPE_CHECKING:  # loaded when the drives run, not with the CLI
    from hil.bench.drives import DrivesOptions


def _msg_rates(heartbeat_ms: float, encoder_ms: float, extra: list[str]) -> dict[int, float]:
    """The periods (ms) of the drives' cyclic messages by command id."""
    from plant_emulator.odrive import CYCLIC

    names = {name: int(cmd) for cmd, name in CYCLIC.items()}
    rates = {0x01: heartbeat_ms, 0x09: encoder_ms}
    for item in extra:
        name, sep, value = item.partition("=")
        if not sep or name not in names:
            raise BadInputError(
                f"--msg-rate {item!r}: use NAME=MS with NAME one of {', '.join(names)}"
            )
        try:
            rates[names[name]] = float(value)
        except ValueError:
            raise BadInputError(f"--msg-rate {item!r}: MS must be a number") from None
    for cmd, ms in rates.items():
        if not (ms >= 0.0 and ms < float("inf")):
            raise BadInputError(f"message rate of cmd 0x{cmd:02x} must be >= 0 ms, got {ms}")
    return rates


# The options of ``hil drives`` longer than a line of its signature, one alias each.
ScenarioArg = Annotated[
    str | None,
    typer.Argument(
        help="Scenario TOML or bundled name: robot, limits, [can] (default: hil run's)."
    ),
]
CanInterfaceOpt = Annotated[
    str | None,
    typer.Option(
        "--can-interface",
        "--interface",
        help="python-can interface: zenoh_can, socketcan, udp_multicast, pcan, ... "
        "(--can-interface, as in hil run).",
    ),
]
ChannelOpt = Annotated[
    str | None,
    typer.Option(
        "--can-channel",
        "--channel",
        help="Bus channel: hil0 (zenoh_can), vcan0, can0, ... (--can-channel, as in hil run).",
    ),
]
CanEndpointOpt = Annotated[str | None, typer.Option(help="zenoh_can's Zenoh endpoint (loopback).")]
ControlRateOpt = Annotated[
    float, typer.Option(help="Hz of the plant and drive controller steps (light form).")
]
HeartbeatOpt = Annotated[
    float, typer.Option(help="Heartbeat period, ms (0: off; firmware 100; light form).")
]
EncoderOpt = Annotated[
    float, typer.Option(help="Get_Encoder_Estimates period, ms (0: off; firmware 10; light form).")
]
MsgRateOpt = Annotated[
    list[str] | None,
    typer.Option(
        help="More cyclic messages, NAME=MS: error, iq, temperature, bus_voltage, "
        "torques, powers (repeatable; light form)."
    ),
]
WatchdogOpt = Annotated[
    float | None,
    typer.Option(
        help="Drive watchdog, s: a drive gets no command for this long and disarms (0: off, "
        "as the firmware ships). Default: [can] watchdog_timeout if set, else 1 s (light form)."
    ),
]
StateRateOpt = Annotated[
    float, typer.Option(help="Publish State (and Status) on Zenoh at this rate, Hz (light form).")
]
EndpointOpt = Annotated[str, typer.Option(help="Zenoh endpoint for State/Status (light form).")]
StatusPeriodOpt = Annotated[
    float, typer.Option(help="Seconds between status lines (0: none; light form).")
]
DurationOpt = Annotated[
    float | None, typer.Option(help="Stop after this many seconds (default: Ctrl-C).")
]
SchedulingOpt = Annotated[
    str | None, typer.Option(help="fifo or other (default: the scenario's; light form).")
]
OutOpt = Annotated[
    Path | None, typer.Option(help="Write summary.json in this folder (light form).")
]
RecordOpt = Annotated[
    Path | None,
    typer.Option(
        help="The run folder the session is recorded into (default runs/drives-*), judged and "
        "reported as any run: hil run --controller external --cmd-path can --until-stopped "
        "(--duration: that long). Waits for your device (--wait-device); the drives at the "
        "firmware's periods, nodes, bitrate and watchdog from the scenario's [can] "
        "(docs/external.md)."
    ),
]
NoRecordOpt = Annotated[
    bool,
    typer.Option(
        "--no-record",
        help="The light form: the drives free running from the start (no wait for a device), "
        "tuned by the options marked (light form), one status line a second and a JSON "
        "summary (--out) instead of a run folder (docs/can.md).",
    ),
]
WaitDeviceOpt = Annotated[
    float, typer.Option(help="Seconds to wait for your device to arm the drives (recorded form).")
]
# Options only the light form (--no-record) takes, and their defaults here: the recorded form
# takes these from the scenario or the firmware's defaults, and refuses any other value (it
# would not be honoured).
_NOT_RECORDED = {
    "bitrate": (None, "the scenario's [can] bitrate"),
    "node_left": (None, "the scenario's [can] node_left"),
    "node_right": (None, "the scenario's [can] node_right"),
    "watchdog_timeout": (None, "the scenario's [can] watchdog_timeout"),
    "control_rate": (1000.0, "the run's plant step"),
    "heartbeat_ms": (100.0, "the firmware's 100 ms"),
    "encoder_ms": (10.0, "the firmware's 10 ms"),
    "msg_rate": (None, "the firmware's cyclic messages"),
    "state_rate": (0.0, "the run's States (every sample)"),
    "endpoint": ("tcp/127.0.0.1:7447", "the run's own Zenoh endpoint"),
    "status_period": (1.0, "the run's progress line"),
    "out": (None, "--record's folder"),
    "scheduling": (None, "the scenario's [realtime] scheduling"),
}
LiveOpt = live_opt("the drives' frames (and State, with --state-rate)")


@app.command("drives")
def drives_cmd(
    scenario: ScenarioArg = None,
    can_interface: CanInterfaceOpt = None,
    channel: ChannelOpt = None,
    bitrate: Annotated[
        int | None, typer.Option(help="Bit/s (hardware, zenoh_can; light form).")
    ] = None,
    can_endpoint: CanEndpointOpt = None,
    node_left: Annotated[
        int | None, typer.Option(help="Left wheel's node id (light form).")
    ] = None,
    node_right: Annotated[
        int | None, typer.Option(help="Right wheel's node id (light form).")
    ] = None,
    control_rate: ControlRateOpt = 1000.0,
    heartbeat_ms: HeartbeatOpt = 100.0,
    encoder_ms: EncoderOpt = 10.0,
    msg_rate: MsgRateOpt = None,
    watchdog_timeout: WatchdogOpt = None,
    state_rate: StateRateOpt = 0.0,
    endpoint: EndpointOpt = "tcp/127.0.0.1:7447",
    status_period: StatusPeriodOpt = 1.0,
    duration: DurationOpt = None,
    scheduling: SchedulingOpt = None,
    out: OutOpt = None,
    live: LiveOpt = None,
    live_host: LiveHostOpt = "127.0.0.1",
    force: ForceOpt = False,
    record: RecordOpt = None,
    no_record: NoRecordOpt = False,
    wait_device: WaitDeviceOpt = 60.0,
) -> None:
    """Run the robot with its two virtual ODrives (CANSimple 0.6) on a CAN bus for any ODrive
    client or controller of yours, until Ctrl-C or SIGTERM (or --duration). The session is
    recorded into a run folder that hil report reads, as any run's: recording, trace, figures
    at the bus and a verdict (docs/external.md). --no-record: the light form, free running
    from the start, one status line a second and a JSON summary (docs/can.md)."""
    if not no_record:
        return _record(dict(locals()))
    if record is not None:
        raise BadInputError("--record and --no-record: choose one")
    from hil.bench.drives import DrivesOptions
    from hil.folder import claim
    from protocol.settings import SCHEDULING

    if scheduling is not None and scheduling not in SCHEDULING:
        raise BadInputError("--scheduling must be fifo or other")
    if duration is not None and not duration > 0:
        raise BadInputError("--duration must be > 0")
    claim.check("--out", out, force)  # before the drives run, not when they stop
    opts = DrivesOptions(
        scenario=scenario,
        interface=can_interface,
        channel=channel,
        bitrate=bitrate,
        can_endpoint=can_endpoint,
        node_left=node_left,
        node_right=node_right,
        control_rate=control_rate,
        msg_rates_ms=_msg_rates(heartbeat_ms, encoder_ms, msg_rate or []),
        watchdog_timeout=watchdog_timeout,
        state_rate=state_rate,
        zenoh_endpoint=endpoint,
        status_period=status_period,
        duration=duration,
        scheduling=scheduling,
        out=out,
    )
    _run_light(opts, live, live_host)


def _run_light(opts: DrivesOptions, live: int | None, live_host: str) -> None:
    """The light form's session (its options checked): the drives, with the live view's
    process around them when asked; exit with the drives' code."""
    import can

    from hil.bench.drives import drives_settings, run_drives
    from hil.bench.live.launch import DrivesLive, check
    from hil.folder import claim

    check(live, live_host)
    if opts.out is not None:
        claim.take(opts.out, "drives")
    watcher = None
    try:
        if live is not None:  # the live view's process around the drives
            settings = drives_settings(opts)
            settings.zenoh_endpoint = opts.zenoh_endpoint  # where the drives publish State, Status
            watcher = DrivesLive(settings, live, live_host)
        code = run_drives(opts)
    except (ValueError, OSError, can.CanError) as exc:  # a refused bus or configuration
        raise BadInputError(str(exc)) from exc
    finally:
        if watcher is not None:
            watcher.close()
    if code:
        raise typer.Exit(code)


def _refuse_unrecorded(given: dict[str, object]) -> None:
    """Exit 2 on an option --record would not honour (module table _NOT_RECORDED)."""
    for name, (default, instead) in _NOT_RECORDED.items():
        if given[name] != default and given[name] != []:
            flag = "--" + name.replace("_", "-")
            raise BadInputError(
                f"{flag} is the light form's (--no-record): the recorded session uses {instead}"
            )


def _record(given: dict[str, object]) -> None:
    """The recorded form: ``hil run --controller external --cmd-path can``, open-ended unless
    --duration; its exit code is the verdict's. An option it would not honour is refused."""
    from hil.commands.run import run
    from hil.folder import claim, new_run_dir

    _refuse_unrecorded(given)
    record = given["record"]
    claim.check("--record", record, bool(given["force"]), default="runs")  # type: ignore[arg-type]

    duration = given["duration"]
    scenario = given["scenario"]
    run(
        scenario=Path(str(scenario)) if scenario is not None else None,
        duration=duration,  # type: ignore[arg-type]
        until_stopped=duration is None,
        cmd_path="can",
        controller="external",
        can_interface=given["can_interface"],  # type: ignore[arg-type]
        can_channel=given["channel"],  # type: ignore[arg-type]
        can_endpoint=given["can_endpoint"],  # type: ignore[arg-type]
        wait_device=given["wait_device"],  # type: ignore[arg-type]
        out=record or new_run_dir(prefix="drives"),  # type: ignore[arg-type]
        live=given["live"],  # type: ignore[arg-type]
        live_host=given["live_host"],  # type: ignore[arg-type]
        force=given["force"],  # type: ignore[arg-type]
    )

"""The CAN tools: ``hil drives`` (the plant and its two virtual ODrives on a CAN bus, until
Ctrl-C), ``hil can-dbc`` (the CANSimple DBC for the node ids in use) and ``hil can-load``
(worst-case bus load of the CAN drive profile at a control rate)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from hil.commands import app
from hil.commands.run import LiveHostOpt, live_opt
from hil.errors import BadInputError, NegativeVerdictError
from hil.options import integer, number, optional_number, out_dir

RATE_MAX = 1e6  # Hz: frames per second of one kind
BITRATE_MAX = 1e9  # bit/s
DRIVES_MAX = 64  # CANSimple node ids are 0..63


@app.command("can-dbc")
def can_dbc(
    nodes: Annotated[
        str, typer.Option(help="Node ids: a range and/or a list, e.g. 0-7 or 0,1,12 (0..63).")
    ] = "0-7",
    out: Annotated[
        Path | None, typer.Option(help="Write odrive_cansimple.dbc in this folder (else: stdout).")
    ] = None,
) -> None:
    """Write the ODrive CANSimple (firmware 0.6) DBC with one message set per node id, so
    that `cantools decode` names every frame of those nodes. The file shipped in the
    package (protocol/can/odrive_cansimple.dbc) is the one for 0-7, as ODrive's own."""
    from protocol.can.dbc import parse_nodes, render

    out_dir("--out", out)
    try:
        text = render(parse_nodes(nodes))
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    if out is None:
        typer.echo(text, nl=False)
        return
    out.mkdir(parents=True, exist_ok=True)
    (out / "odrive_cansimple.dbc").write_text(text, encoding="utf-8")
    typer.echo(f"wrote {out / 'odrive_cansimple.dbc'} for nodes {nodes}")


@app.command("can-load")
def can_load(
    rate: Annotated[float, typer.Option(help="Control rate in Hz.")],
    bitrate: Annotated[float, typer.Option(help="CAN bitrate in bit/s.")],
    drives: Annotated[int, typer.Option(help="Drives on the bus.")] = 2,
    heartbeat_rate: Annotated[
        float, typer.Option(help="Heartbeats/s per drive (firmware: 10).")
    ] = 10.0,
    encoder_rate: Annotated[
        float | None,
        typer.Option(help="Encoder estimates per second per drive (default: the control rate)."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON, not a table.")] = False,
    out: Annotated[
        Path | None, typer.Option(help="Also write can_load.json in this folder.")
    ] = None,
) -> None:
    """Bit length of every periodic frame (classical CAN, 11-bit id, worst-case stuffing:
    47 + 8 DLC + floor((34 + 8 DLC - 1)/4) bits, 3-bit interframe space included; Davis
    et al. 2007) and the bus load in percent. Exit code 1 (with a warning) when the load
    exceeds 100%, 2 on bad input."""
    from protocol.can.bus_load import bus_load_percent, profile_frames

    rate = number("--rate", rate, 0.0, RATE_MAX, positive=True)
    bitrate = number("--bitrate", bitrate, 0.0, BITRATE_MAX, positive=True)
    drives = integer("--drives", drives, 1, DRIVES_MAX)
    heartbeat_rate = number("--heartbeat-rate", heartbeat_rate, 0.0, RATE_MAX)
    encoder_rate = optional_number("--encoder-rate", encoder_rate, 0.0, RATE_MAX)
    out_dir("--out", out)
    try:
        frames = profile_frames(rate, drives, heartbeat_rate, encoder_rate)
        load = bus_load_percent(frames, bitrate)
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    report = {
        "rate_hz": rate,
        "bitrate_bps": bitrate,
        "drives": drives,
        "frames": [
            {
                "name": f.name,
                "dlc": f.dlc,
                "bits": f.bits,
                "frames_per_second": f.per_second,
                "bits_per_second": f.bits_per_second,
            }
            for f in frames
        ],
        "bits_per_second": sum(f.bits_per_second for f in frames),
        "load_percent": load,
    }
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "can_load.json").write_text(json.dumps(report, indent=2) + "\n")
    if as_json:
        typer.echo(json.dumps(report, indent=2))
    else:
        typer.echo(f"{'frame':<24}{'DLC':>4}{'bits':>6}{'frames/s':>11}{'bit/s':>12}")
        for f in frames:
            typer.echo(
                f"{f.name:<24}{f.dlc:>4}{f.bits:>6}{f.per_second:>11.1f}{f.bits_per_second:>12.0f}"
            )
        typer.echo(
            f"total {report['bits_per_second']:.0f} bit/s of {bitrate:.0f}: bus load {load:.2f}%"
        )
    if load > 100.0:
        typer.echo(f"warning: bus load {load:.1f}% > 100%: frames queue without bound", err=True)
        raise NegativeVerdictError(f"CAN bus overloaded ({load:.1f}%)")


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
ControlRateOpt = Annotated[float, typer.Option(help="Hz of the plant and drive controller steps.")]
HeartbeatOpt = Annotated[float, typer.Option(help="Heartbeat period, ms (0: off; firmware 100).")]
EncoderOpt = Annotated[
    float, typer.Option(help="Get_Encoder_Estimates period, ms (0: off; firmware 10).")
]
MsgRateOpt = Annotated[
    list[str] | None,
    typer.Option(
        help="More cyclic messages, NAME=MS: error, iq, temperature, bus_voltage, "
        "torques, powers (repeatable)."
    ),
]
WatchdogOpt = Annotated[
    float | None,
    typer.Option(
        help="Drive watchdog, s: a drive gets no command for this long and disarms (0: off, "
        "as the firmware ships). Default: [can] watchdog_timeout if set, else 1 s."
    ),
]
StateRateOpt = Annotated[
    float, typer.Option(help="Publish State (and Status) on Zenoh at this rate, Hz.")
]
EndpointOpt = Annotated[str, typer.Option(help="Zenoh endpoint for State/Status.")]
StatusPeriodOpt = Annotated[float, typer.Option(help="Seconds between status lines (0: none).")]
DurationOpt = Annotated[
    float | None, typer.Option(help="Stop after this many seconds (default: Ctrl-C).")
]
SchedulingOpt = Annotated[str | None, typer.Option(help="fifo or other (default: the scenario's).")]
OutOpt = Annotated[Path | None, typer.Option(help="Also write summary.json in this folder.")]
LiveOpt = live_opt("the drives' frames (and State, with --state-rate)")


@app.command("drives")
def drives_cmd(
    scenario: ScenarioArg = None,
    can_interface: CanInterfaceOpt = None,
    channel: ChannelOpt = None,
    bitrate: Annotated[int | None, typer.Option(help="Bit/s (hardware, zenoh_can).")] = None,
    can_endpoint: CanEndpointOpt = None,
    node_left: Annotated[int | None, typer.Option(help="Left wheel's node id.")] = None,
    node_right: Annotated[int | None, typer.Option(help="Right wheel's node id.")] = None,
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
) -> None:
    """Run the robot with its two virtual ODrives (CANSimple 0.6) on a CAN bus for any
    ODrive client, free running (no start gate), until Ctrl-C or SIGTERM: one status line
    a second, a JSON summary at the end (docs/can.md)."""
    from hil.live.launch import DrivesLive, check
    from hil.run.drives import DrivesOptions, drives_settings, run_drives

    if scheduling not in (None, "fifo", "other"):
        raise BadInputError("--scheduling must be fifo or other")
    if duration is not None and not duration > 0:
        raise BadInputError("--duration must be > 0")
    out_dir("--out", out)  # before the drives run, not when they stop
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
    import can

    check(live, live_host)
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

"""``hil drives``: the plant and its two virtual ODrives on a CAN bus, until Ctrl-C."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from hil.commands.run import LiveHostOpt, live_opt
from hil.errors import BadInputError
from hil.options import out_dir


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
            ms = float(value)
        except ValueError:
            raise BadInputError(f"--msg-rate {item!r}: MS must be a number") from None
        rates[names[name]] = ms
    for cmd, ms in rates.items():
        if not (ms >= 0.0 and ms < float("inf")):
            raise BadInputError(f"message rate of cmd 0x{cmd:02x} must be >= 0 ms, got {ms}")
    return rates


# The options of ``hil drives``, one alias each, so that the command's signature stays short.
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
BitrateOpt = Annotated[int | None, typer.Option(help="Bit/s (hardware, zenoh_can).")]
CanEndpointOpt = Annotated[str | None, typer.Option(help="zenoh_can's Zenoh endpoint (loopback).")]
NodeLeftOpt = Annotated[int | None, typer.Option(help="Left wheel's node id.")]
NodeRightOpt = Annotated[int | None, typer.Option(help="Right wheel's node id.")]
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


def register(app: typer.Typer) -> None:
    @app.command("drives")
    def drives(
        scenario: ScenarioArg = None,
        can_interface: CanInterfaceOpt = None,
        channel: ChannelOpt = None,
        bitrate: BitrateOpt = None,
        can_endpoint: CanEndpointOpt = None,
        node_left: NodeLeftOpt = None,
        node_right: NodeRightOpt = None,
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
        from hil.run.drives import DrivesOptions

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

        from hil.live.launch import check

        check(live, live_host)
        try:
            code = _run_watched(opts, live, live_host)
        except (ValueError, OSError, can.CanError) as exc:  # a refused bus or configuration
            raise BadInputError(str(exc)) from exc
        if code:
            raise typer.Exit(code)


def _run_watched(opts: Any, live: int | None, live_host: str) -> int:
    """:func:`hil.run.drives.run_drives`, with the live view's process around it if asked."""
    from hil.run.drives import drives_settings, run_drives

    if live is None:
        return run_drives(opts)
    from hil.live.launch import DrivesLive

    settings = drives_settings(opts)
    settings.zenoh_endpoint = opts.zenoh_endpoint  # where the drives publish State, Status
    watcher = DrivesLive(settings, live, live_host)
    try:
        return run_drives(opts)
    finally:
        watcher.close()

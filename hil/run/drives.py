"""``hil drives``: the scenario (default: ``hil run``'s) resolved into settings, then the virtual
drives of :mod:`plant_emulator.drives` on them (which need no ``hil``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plant_emulator import drives
from protocol.can.codec import Cmd
from protocol.settings import RunSettings


@dataclass
class DrivesOptions:
    """What ``hil drives`` runs (see ``hil drives --help``)."""

    scenario: str | None = None  # a file or bundled name; None: hil run's default scenario
    interface: str | None = None  # python-can interface; None: the scenario's [can]
    channel: str | None = None
    bitrate: int | None = None
    can_endpoint: str | None = None  # zenoh_can's endpoint
    node_left: int | None = None
    node_right: int | None = None
    control_rate: float = 1000.0  # Hz: plant steps and drive controller steps
    msg_rates_ms: dict[int, float] = field(
        default_factory=lambda: {Cmd.HEARTBEAT: 100.0, Cmd.GET_ENCODER_ESTIMATES: 10.0}
    )
    watchdog_timeout: float | None = None  # s; None: the scenario's [can] (0 = off)
    state_rate: float = 0.0  # Hz of State on Zenoh (0: no Zenoh at all)
    zenoh_endpoint: str = "tcp/127.0.0.1:7447"
    robot_id: str | None = None
    status_period: float = 1.0  # s between status lines (0: none)
    duration: float | None = None  # s, then exit as on SIGINT (None: until a signal)
    scheduling: str | None = None  # "fifo" / "other"; None: the scenario's [realtime]
    out: Path | None = None  # where summary.json goes (None: stdout only)


def _scenario(name: str | None) -> Any:
    from hil.scenario import load_scenario, loads_scenario

    if name is None:
        from hil.run.defaults import PAPER_TRACKING_TOML

        return loads_scenario(PAPER_TRACKING_TOML)
    from hil.bundled import resolve_scenario

    return load_scenario(resolve_scenario(name))


def drives_settings(opts: DrivesOptions) -> RunSettings:
    """The scenario with the command line's overrides, as the drives read it."""
    import dataclasses

    from hil.run.settings import scenario_settings

    sc = _scenario(opts.scenario)
    can_table = dataclasses.asdict(sc.can)
    for key in ("interface", "channel", "bitrate", "node_left", "node_right", "watchdog_timeout"):
        value = getattr(opts, key)
        if value is not None:
            can_table[key] = value
    # The drives land commands as they come: no replay file to read.
    settings = scenario_settings(
        sc, can=can_table, can_endpoint=opts.can_endpoint or "", replay=None, jitter_kind="uniform"
    )
    if opts.robot_id:
        settings.robot_id = opts.robot_id
    if opts.scheduling:
        settings.scheduling = opts.scheduling
    return settings


def run_drives(opts: DrivesOptions) -> int:
    """Resolve, then run the drives until a signal (or ``duration``); the exit code."""
    run = drives.DrivesOptions(
        control_rate=opts.control_rate,
        msg_rates_ms=opts.msg_rates_ms,
        state_rate=opts.state_rate,
        zenoh_endpoint=opts.zenoh_endpoint,
        status_period=opts.status_period,
        duration=opts.duration,
        out=opts.out,
    )
    return drives.run_drives(run, drives_settings(opts))

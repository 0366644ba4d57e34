"""``hil drives``: the scenario (default: ``hil run``'s) resolved into settings, then the virtual
drives of :mod:`plant_emulator.drives` on them (which need no ``hil``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from hil.bench.defaults import PAPER_TRACKING_TOML
from hil.bench.settings import scenario_settings
from hil.bundled import resolve_scenario
from hil.scenario import load_scenario, loads_scenario
from plant_emulator import drives
from protocol.settings import RunSettings

DEFAULT_WATCHDOG_S = 1.0  # the drives' watchdog unless the scenario or --watchdog-timeout says


@dataclass
class DrivesOptions(drives.DrivesOptions):
    """What ``hil drives`` runs: the fields of :class:`plant_emulator.drives.DrivesOptions`,
    and here the scenario and the command line's overrides of it."""

    scenario: str | None = None  # a file or bundled name; None: hil run's default scenario
    interface: str | None = None  # python-can interface; None: the scenario's [can]
    channel: str | None = None
    bitrate: int | None = None
    can_endpoint: str | None = None  # zenoh_can's endpoint
    node_left: int | None = None
    node_right: int | None = None
    watchdog_timeout: float | None = None  # s (0 = off); None: [can]'s, else DEFAULT_WATCHDOG_S
    robot_id: str | None = None
    scheduling: str | None = None  # "fifo" / "other"; None: the scenario's [realtime]


def drives_settings(opts: DrivesOptions) -> RunSettings:
    """The scenario with the command line's overrides, as the drives read it."""
    if opts.scenario is None:
        sc = loads_scenario(PAPER_TRACKING_TOML)
    else:
        sc = load_scenario(resolve_scenario(opts.scenario))
    can_table = dataclasses.asdict(sc.can)
    if not can_table.get("watchdog_timeout"):
        # A client that dies or forgets its torque must not leave the robot driven: on here,
        # where nothing else watches the bus (in a run, the plant's command timeout does).
        can_table["watchdog_timeout"] = DEFAULT_WATCHDOG_S
    keys = ("interface", "channel", "bitrate", "node_left", "node_right", "watchdog_timeout")
    can_table.update((k, getattr(opts, k)) for k in keys if getattr(opts, k) is not None)
    # The drives land commands as they come: no replay file to read.
    settings = scenario_settings(
        sc, can=can_table, can_endpoint=opts.can_endpoint or "", replay=None, jitter_kind="uniform"
    )
    for key in ("robot_id", "scheduling"):  # the command line's, over the scenario's
        if getattr(opts, key):
            setattr(settings, key, getattr(opts, key))
    return settings


def run_drives(opts: DrivesOptions) -> int:
    """Resolve, then run the drives until a signal (or ``duration``); the exit code."""
    return drives.run_drives(opts, drives_settings(opts))

"""One run, resolved: everything the two services (and the virtual drives) need, in one file.

``hil`` parses the scenario once (its checks, its defaults, the design context of the law,
a replay file's latencies) and writes ``run_settings.json``; each service builds its core from
that file alone (``python -m controller_service SETTINGS``, ``python -m plant_emulator
SETTINGS``), so the services never read a scenario and need no ``hil``. Controller and plant
agree on the epoch, the control period, the paths and the endpoints because they read the same
file.

The control period is ``ts`` in seconds (the paper's T_s) everywhere in code; a rate in Hz
(``[realtime] rate``, ``--rate``) is converted once, where ``hil`` resolves the scenario.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from protocol.errors import BadInputError
from protocol.robot import Limits

CMD_PATHS = ("zenoh", "can")
# the services' scheduling policy: SCHED_FIFO (real-time priority) or the default SCHED_OTHER
SCHEDULING = ("fifo", "other")
TRIGGERS = ("periodic", "on_state")
# where the periodic controller ticks after the sample (controller_service.tick_phase)
TICK_PHASES = ("half", "auto")
# "poll": the services hold the CPUs out of slow idle states (runtime.realtime.hold_cpu_latency)
IDLE_POLICIES = ("poll", "os")
SETTINGS_VERSION = 2
TS_MIN = 1.0 / 20_000.0  # s: the services' fastest period (20 kHz)


def period_s(rate_hz: float) -> float:
    """The period in seconds of a rate in Hz: the one rate-to-period conversion."""
    return 1.0 / rate_hz


def period_ns(seconds: float) -> int:
    """A period in seconds as whole nanoseconds (what the services' clocks count)."""
    return round(seconds * 1e9)


def _initial() -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "theta": 0.0, "v": 0.0, "omega": 0.0, "z1": 0.0, "z2": 0.0}


def _design() -> dict[str, float]:
    return {"s1": 0.0, "s2": 0.0, "mu1": 0.5, "mu2": 0.2, "k1": 1.0, "k2": 1.0}


@dataclass
class RunSettings:
    """The resolved run (written by ``hil``, read by the services; see the module docstring)."""

    settings_version: int = SETTINGS_VERSION
    scenario_path: str = ""  # provenance only: the services never read it
    robot_id: str = "robot0"
    epoch_ns: int = 0
    duration: float = 10.0
    ts: float = 0.001  # s, the control period T_s
    sensor_ts: float = 0.001  # s between the plant's State samples
    trigger: str = "periodic"
    tick_phase: str = "half"  # where the periodic ticks fall after the sample (half, auto)
    lockstep: bool = False
    state_timeout: float = 0.05
    command_timeout: float = 0.05
    scheduling: str = "fifo"
    idle: str = "poll"  # the CPUs' idle states while the service runs (runtime.realtime)
    cmd_path: str = "zenoh"
    can_live: bool = True
    can: dict[str, Any] = field(default_factory=dict)
    robot: dict[str, Any] = field(default_factory=dict)
    # What the bench sets on its virtual ODrives beyond the firmware's defaults (names of
    # plant_emulator.odrive.DriveConfig: torque_limit, current_limit, vel_limit), resolved by
    # hil from [robot] and [limits] (docs/can.md, "Defaults"); empty in a file written before
    # it existed: the plant derives the same values.
    drives: dict[str, Any] = field(default_factory=dict)
    zenoh_mode: str = "peer"
    zenoh_endpoint: str = "tcp/127.0.0.1:7447"
    can_endpoint: str = "tcp/127.0.0.1:7449"
    # --- the law: [controller] as given, the virtual robot (3), the design context ----------
    controller: dict[str, Any] = field(default_factory=lambda: {"law": "unified"})
    reference: dict[str, Any] = field(default_factory=dict)
    base_dir: str = "."  # where a reference's relative file paths start
    # folders a user's law module is looked up in after the installed packages (the scenario's
    # folder and hil's working directory, controller_service.registry.law_path_for)
    law_path: list[str] = field(default_factory=list)
    limits: dict[str, float] = field(default_factory=lambda: asdict(Limits()))
    # s1, s2 of Assumption 1 and mu1, mu2, k1, k2 of Assumption 2, as the design used them
    design: dict[str, float] = field(default_factory=_design)
    # the robot at t = 0 and the adaptive states z1(0), z2(0) of (8)
    initial: dict[str, float] = field(default_factory=_initial)
    # --- the plant: model (1) ---------------------------------------------------------------
    plant_step: float = 0.0001  # s, the RK4 step (ts divided into whole steps)
    lag: float = 0.0  # s, the actuator lag
    friction: list[float] = field(default_factory=lambda: [0.0, 0.0])  # 1/s on v, omega
    max_speed: list[float] = field(default_factory=list)  # m/s, rad/s; empty: no top speed
    disturbance: dict[str, Any] = field(default_factory=dict)  # [disturbance]
    sensor: dict[str, Any] = field(default_factory=dict)  # noise_std, quantization, seed
    # --- when commands land: delay, jitter (seeded) or a replay's latencies -----------------
    delay: float = 0.0
    jitter: float = 0.0
    jitter_kind: str = "uniform"
    seed: int = 0
    replay: list[float] | None = None  # s, the latencies of [timing] replay, read by hil
    # [faults] of the scenario (protocol.faults.Faults as a dict); empty = no injection.
    faults: dict[str, Any] = field(default_factory=dict)
    out_dir: str = "."
    cpu_controller: int | None = None
    cpu_plant: int | None = None
    spin_us: float = 0.0
    start_timeout: float = 60.0  # s a service waits for the run's start message

    @property
    def limits_value(self) -> Limits:
        """The constraints (2) as :class:`protocol.robot.Limits`."""
        return Limits(**self.limits)

    def validate(self) -> None:
        """Every value a service relies on; a bad one raises :class:`BadInputError`."""
        if self.cmd_path not in CMD_PATHS:
            raise BadInputError(f"cmd path must be one of {CMD_PATHS}, got {self.cmd_path!r}")
        if self.lockstep and self.cmd_path == "can":
            raise BadInputError("lockstep exchanges its commands on Zenoh: cmd path can refused")
        if self.trigger not in TRIGGERS:
            raise BadInputError(f"[realtime] trigger must be one of {TRIGGERS}")
        if self.tick_phase not in TICK_PHASES:
            raise BadInputError(f"[realtime] tick_phase must be one of {TICK_PHASES}")
        for name in ("ts", "sensor_ts", "state_timeout", "command_timeout", "plant_step"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (
                isinstance(v, int | float) and math.isfinite(v) and v > 0
            ):
                raise BadInputError(f"{name} must be a positive number, got {v!r}")
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise BadInputError(f"duration must be positive, got {self.duration!r}")
        if self.ts < TS_MIN * (1 - 1e-12):
            raise BadInputError("[realtime] rate above 20 kHz is not supported")
        if self.scheduling not in SCHEDULING:
            raise BadInputError("[realtime] scheduling must be 'fifo' or 'other'")
        if self.idle not in IDLE_POLICIES:
            raise BadInputError(f"[realtime] idle must be one of {IDLE_POLICIES}")
        if not isinstance(self.drives, dict):
            raise BadInputError(f"drives must be a table, got {self.drives!r}")
        if not isinstance(self.faults, dict):
            raise BadInputError(f"faults must be a table, got {self.faults!r}")
        for key, v in self.faults.items():
            if isinstance(v, bool) or not isinstance(v, int | float) or not (v >= 0):
                raise BadInputError(f"[faults] {key} must be a number >= 0, got {v!r}")
        try:
            self.limits_value  # noqa: B018 (building it is the check)
        except TypeError as exc:
            raise BadInputError(f"limits: {exc}") from exc
        if self.jitter_kind == "replay" and not self.replay:
            raise BadInputError("jitter_kind 'replay' needs the replay's latencies")

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(asdict(self), indent=2))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunSettings:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known - _LEGACY)
        if unknown:
            raise BadInputError(f"unknown key(s) {', '.join(unknown)}")
        values = {k: v for k, v in data.items() if k in known}
        # A folder written before the period had one name (hil recover reads old folders).
        if "ts" not in values and ("ts_s" in data or "rate_hz" in data):
            ts_s = data.get("ts_s")
            values["ts"] = ts_s if ts_s is not None else period_s(data["rate_hz"])
        if "sensor_ts" not in values and "sensor_rate_hz" in data:
            values["sensor_ts"] = period_s(data["sensor_rate_hz"])
        return cls(**values)

    @classmethod
    def load(cls, path: str | Path) -> RunSettings:
        """Read a settings file; anything unreadable raises :class:`BadInputError`."""
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise BadInputError(f"settings {path}: cannot read ({exc})") from exc
        if not isinstance(data, dict):
            raise BadInputError(f"settings {path}: not a JSON object")
        try:
            return cls.from_dict(data)
        except (TypeError, ZeroDivisionError, BadInputError) as exc:
            raise BadInputError(f"settings {path}: {exc}") from exc

    # --- the CAN edge, the same for both services and the recorder ---------------------------
    def can_settings(self) -> Any:
        """The run's ``[can]`` table parsed once: interface, channel, node ids, timeouts."""
        from protocol.can.bus_factory import CanSettings

        return CanSettings.from_table(dict(self.can))

    def motor_limit(self) -> tuple[Any, float]:
        """The robot's wheel geometry and the largest motor torque (2)'s varpi1, varpi2 allow."""
        from protocol.can.wheel_mapping import RobotGeometry, motor_torque_limit

        geom = RobotGeometry(**self.robot)
        lim = self.limits_value
        return geom, motor_torque_limit(geom, lim.varpi1, lim.varpi2)

    def open_can_bus(self) -> Any:
        """The run's CAN bus, or None when CAN is neither applied nor live as a shadow."""
        if not (self.can_live or self.cmd_path == "can"):
            return None
        from protocol.can.bus_factory import open_bus

        cs = self.can_settings()
        extra: dict[str, Any] = {}
        if cs.interface == "zenoh_can":
            extra["endpoint"] = self.can_endpoint
        return open_bus(cs, **extra)


# Keys of settings files written before SETTINGS_VERSION 2 (read, converted, dropped).
_LEGACY = frozenset({"rate_hz", "sensor_rate_hz", "ts_s"})

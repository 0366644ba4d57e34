"""Scenario files (documented key by key in docs/scenario.md).

One TOML file describes one closed loop. Every table is optional except [reference] and
[initial]; defaults are the paper's Section 4 set-up. Everything is checked on load, before any
command builds or runs anything (docs/scenario.md "Errors"): a bad file raises
:class:`hil.errors.BadInputError` with one line naming the key as ``[table] key`` (exit 2).
[reference] and [controller] stay plain dicts, checked by their owners' static checks (no file
read, nothing imported) and built by :func:`build_loop`, which also names the keys of a broken
design condition.
"""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller_service.design import DesignError
from controller_service.laws.base import DesignContext, Limits
from controller_service.references import build_reference as _build
from controller_service.references import check_table as check_reference
from controller_service.registry import build_controller, law_path_for, resolved_controller_table
from controller_service.registry import check_table as check_controller
from hil.bundled import resolve_scenario
from hil.errors import BadInputError
from hil.limits import LIMIT_NAMES
from hil.options import choice, describe, locator, number, plain_string, type_name
from hil.provenance import Toml, provenance
from plant_emulator.disturbances import KINDS as DISTURBANCE_KINDS
from plant_emulator.disturbances import Disturbance, max_abs
from plant_emulator.dynamics import Drag
from plant_emulator.sensors import Sensor
from protocol.can.bus_factory import CanSettings
from protocol.can.wheel_mapping import RobotGeometry
from protocol.faults import Faults
from protocol.messages import ANGLE_MAX, POSITION_MAX, SPEED_MAX, TORQUE_MAX, TURN_RATE_MAX
from protocol.settings import IDLE_POLICIES, SCHEDULING, TICK_PHASES, TRIGGERS
from protocol.versions import SIM_SCHEMA_VERSION as SCHEMA_VERSION  # hil.sim.core's name

_REL_TOL = 1e-12

# Declared ranges (docs/scenario.md, "Errors"). The state, the limits and the torques stay
# within what the protocol's messages carry (protocol.messages), so a run never meets a value
# its wire refuses; times and counts stay where the simulator's arrays and the services' integer
# nanoseconds are exact.
MAX_MAGNITUDE = 1e9  # any number without a range of its own: |value| <= 1e9
SEED_MAX = 2**32 - 1
TS_MIN, TS_MAX = 1e-6, 10.0  # s, the control period
DELAY_MAX = 1e6  # s, delay and jitter
DURATION_MAX = 1e7  # s
RATE_MAX = 20_000.0  # Hz, as hil run
TIMEOUT_MAX = 3600.0  # s
MAX_SAMPLES = 10_000_000  # control samples of one loop: duration / ts
MAX_SUBSTEPS = 100_000  # plant steps per control period: ts / [plant] step
SWEEP_SEEDS_MAX = 10_000


@dataclass(frozen=True)
class Initial:
    """[initial]: the robot's state at t = 0 and the adaptive states z1(0), z2(0) of (8)."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    v: float = 0.0
    omega: float = 0.0
    z1: float = 0.0
    z2: float = 0.0


@dataclass(frozen=True)
class PlantConfig:
    """[plant]: RK4 step (None = ts/10), sensor noise and quantization, actuator lag, and the
    losses model (1) leaves out: viscous friction and a top speed (off, as in the paper)."""

    step: float | None = None
    noise_std: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    noise_seed: int = 0
    quantization: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    lag: float = 0.0
    friction: tuple[float, ...] = (0.0, 0.0)  # 1/s on v and omega: v' = tau1 + d1 - c_v v
    max_speed: tuple[float, ...] = ()  # (m/s, rad/s): |v|, |omega| held below; (): none

    @property
    def drag(self) -> Drag:
        """The friction and top speed as the plant integrates them."""
        top = self.max_speed or (math.inf, math.inf)
        return Drag(self.friction[0], self.friction[1], top[0], top[1])


@dataclass(frozen=True)
class TimingConfig:
    """[timing]: control period, sample-to-apply delay, extra delay (jitter) and its kind."""

    ts: float = 0.001
    delay: float = 0.0
    jitter: float = 0.0
    jitter_kind: str = "uniform"
    replay: str = ""
    seed: int = 0


@dataclass(frozen=True)
class RunConfig:
    duration: float = 150.0


@dataclass(frozen=True)
class RobotConfig(RobotGeometry):
    """[robot]: the physical robot behind the unit-mass model (1), for the CAN wheel mapping
    (:class:`protocol.can.wheel_mapping.RobotGeometry`'s keys and defaults)."""


@dataclass(frozen=True)
class RealtimeConfig:
    rate: float | None = None
    sensor_rate: float | None = None
    trigger: str = "periodic"
    tick_phase: str = "half"
    state_timeout: float = 0.05
    command_timeout: float = 0.05
    scheduling: str = "fifo"
    idle: str = "poll"


@dataclass(frozen=True)
class CanConfig:
    # The defaults of protocol.can.bus_factory.CanSettings: Zenoh-carried CAN works across
    # processes on any kernel, without root, and never leaves the host.
    interface: str = CanSettings.interface
    channel: str = CanSettings.channel
    bitrate: int = CanSettings.bitrate
    node_left: int = CanSettings.node_left
    node_right: int = CanSettings.node_right
    heartbeat_timeout: float = CanSettings.heartbeat_timeout
    watchdog_timeout: float = CanSettings.watchdog_timeout


@dataclass(frozen=True)
class ZenohConfig:
    mode: str = "peer"
    endpoints: tuple[str, ...] = ()
    robot_id: int = 0


@dataclass(frozen=True)
class SweepConfig:
    ts: tuple[float, ...] = ()
    delay: tuple[float, ...] = ()
    jitter: tuple[float, ...] = ()
    seeds: int = 1


@dataclass(frozen=True)
class FaultsConfig(Faults):
    """[faults]: fault injection on the wire (0 = off), the keys of :class:`protocol.faults.Faults`
    (seeded; the services log every fault they inject), checked where the scenario is read."""

    def __post_init__(self) -> None:
        for key in ("can_frame_loss", "feedback_loss"):
            if not getattr(self, key) <= 1.0:
                raise BadInputError(
                    f"[faults] {key} must be a probability in [0, 1], got {getattr(self, key)}"
                )
        for what in (
            "delay_burst",
            "can_bus_off",
            "state_drop_burst",
            "command_drop_burst",
            "drive_silent",
            "feedback_frozen",
        ):
            every, length = getattr(self, f"{what}_every"), getattr(self, f"{what}_length")
            if every > 0 and not 0 < length <= every:
                raise BadInputError(
                    f"[faults] {what}_length must be in (0, {what}_every = {every}], got {length}"
                )


RATE_BPS_MIN, RATE_BPS_MAX = 1000.0, 1e11  # bit/s, [impair] rate_bps (0 = no limit)


@dataclass(frozen=True)
class ImpairConfig:
    """[impair]: packets of the run's own links dropped (``loss`` at random or every
    ``loss_every``-th) and the loopback rate-limited, by the kernel in the run's private network
    namespace (:mod:`hil.bench.impair`); only ``hil run`` reads it."""

    loss: float = 0.0
    loss_every: int = 0
    rate_bps: float = 0.0
    on: str = "all"
    can_frames: str = "all"

    def __post_init__(self) -> None:
        if self.loss > 0 and self.loss_every > 0:
            raise BadInputError(
                f"[impair] loss = {self.loss:g} and loss_every = {self.loss_every} exclude each "
                "other: set one (random or every n-th packet)"
            )
        if 0 < self.rate_bps < RATE_BPS_MIN:
            raise BadInputError(
                f"[impair] rate_bps must be 0 (no limit) or at least {RATE_BPS_MIN:g} bit/s, "
                f"got {self.rate_bps:g}"
            )
        if self.can_frames != "all" and self.on != "can":
            raise BadInputError(
                f"[impair] can_frames = {self.can_frames!r} selects CAN frames: it needs "
                f"on = 'can', got on = {self.on!r}"
            )


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario: one frozen value per table; ``base_dir`` resolves relative paths."""

    reference: Mapping[str, Any]
    initial: Initial
    limits: Limits = field(default_factory=Limits)
    disturbance: Disturbance = field(default_factory=Disturbance)
    controller: Mapping[str, Any] = field(default_factory=lambda: {"law": "unified"})
    plant: PlantConfig = PlantConfig()
    timing: TimingConfig = TimingConfig()
    run: RunConfig = RunConfig()
    robot: RobotConfig = RobotConfig()
    realtime: RealtimeConfig = RealtimeConfig()
    can: CanConfig = CanConfig()
    zenoh: ZenohConfig = ZenohConfig()
    sweep: SweepConfig = SweepConfig()
    faults: FaultsConfig = FaultsConfig()
    impair: ImpairConfig | None = None  # None: no [impair] table, the run keeps the host's network
    base_dir: Path = Path(".")
    source: str = ""

    @property
    def plant_step(self) -> float:
        """The RK4 step actually used: ts divided into a whole number of steps <= [plant] step."""
        return self.timing.ts / self.substeps

    @property
    def substeps(self) -> int:
        step = self.plant.step if self.plant.step is not None else self.timing.ts / 10.0
        return max(1, math.ceil(self.timing.ts / step - 1e-9))

    @property
    def sensor(self) -> Sensor:
        p = self.plant
        return Sensor(p.noise_std, p.quantization, p.noise_seed)  # type: ignore[arg-type]

    def with_overrides(
        self,
        duration: float | None = None,
        ts: float | None = None,
        names: tuple[str, str] = ("--duration", "--ts"),
    ) -> Scenario:
        """The same scenario with a new run duration and/or control period (command line);
        a bad value raises BadInputError naming the option (``names``)."""
        out, dur_name, ts_name = self, "[run] duration", "[timing] ts"
        if duration is not None:
            dur_name = names[0]
            duration = number(dur_name, duration, 0.0, DURATION_MAX, positive=True)
            out = dataclasses.replace(out, run=RunConfig(duration))
        if ts is not None:
            ts_name = names[1]
            ts = number(ts_name, ts, TS_MIN, TS_MAX)
            out = dataclasses.replace(out, timing=dataclasses.replace(out.timing, ts=ts))
        check_loop_size(out, dur_name, ts_name)
        return out


def _keys(table: str, *keys: str) -> set[tuple[str, str]]:
    return {(table, key) for key in keys}


# table name -> its dataclass
_TABLES: dict[str, type] = {
    "limits": Limits,
    "disturbance": Disturbance,
    "initial": Initial,
    "plant": PlantConfig,
    "timing": TimingConfig,
    "run": RunConfig,
    "robot": RobotConfig,
    "realtime": RealtimeConfig,
    "can": CanConfig,
    "zenoh": ZenohConfig,
    "sweep": SweepConfig,
    "faults": FaultsConfig,
    "impair": ImpairConfig,
}
_CHOICES: dict[tuple[str, str], tuple[str, ...]] = {
    ("disturbance", "kind"): DISTURBANCE_KINDS,
    ("timing", "jitter_kind"): ("uniform", "normal", "replay"),
    ("realtime", "trigger"): TRIGGERS,
    ("realtime", "tick_phase"): TICK_PHASES,
    ("realtime", "scheduling"): SCHEDULING,
    ("realtime", "idle"): IDLE_POLICIES,
    ("zenoh", "mode"): ("peer", "client", "router"),
    ("impair", "on"): ("all", "can", "zenoh"),
    ("impair", "can_frames"): ("all", "torque"),
}
# (table, key) -> (low, high): low <= value <= high (and > 0 where _POSITIVE says so); every
# other number |value| <= MAX_MAGNITUDE. Items of a list are checked one by one.
_RANGES: dict[tuple[str, str], tuple[float, float]] = {
    ("limits", "phi1"): (0.0, SPEED_MAX),
    ("limits", "phi2"): (0.0, TURN_RATE_MAX),
    **dict.fromkeys(_keys("limits", "varpi1", "varpi2"), (0.0, TORQUE_MAX)),
    **dict.fromkeys(_keys("initial", "x", "y"), (-POSITION_MAX, POSITION_MAX)),
    ("initial", "theta"): (-ANGLE_MAX, ANGLE_MAX),
    ("initial", "v"): (-SPEED_MAX, SPEED_MAX),
    ("initial", "omega"): (-TURN_RATE_MAX, TURN_RATE_MAX),
    **dict.fromkeys(_keys("disturbance", "s1", "s2"), (0.0, TORQUE_MAX)),
    **dict.fromkeys(
        _keys("disturbance", "value1", "value2", "amplitude1", "amplitude2"),
        (-TORQUE_MAX, TORQUE_MAX),
    ),
    ("disturbance", "freq"): (0.0, 1e6),
    ("disturbance", "period"): (1e-6, DURATION_MAX),
    ("disturbance", "seed"): (0, SEED_MAX),
    ("plant", "step"): (0.0, TS_MAX),
    **dict.fromkeys(
        _keys("plant", "noise_std", "quantization", "lag", "friction", "max_speed"), (0.0, 1e6)
    ),
    ("plant", "noise_seed"): (0, SEED_MAX),
    ("timing", "ts"): (TS_MIN, TS_MAX),
    **dict.fromkeys(_keys("timing", "delay", "jitter"), (0.0, DELAY_MAX)),
    ("timing", "seed"): (0, SEED_MAX),
    ("run", "duration"): (0.0, DURATION_MAX),
    **dict.fromkeys(_keys("robot", "mass", "yaw_inertia"), (0.0, 1e6)),
    **dict.fromkeys(_keys("robot", "wheel_radius", "half_track"), (1e-4, 100.0)),
    ("robot", "gear_ratio"): (1e-3, 1e6),
    **dict.fromkeys(_keys("realtime", "rate", "sensor_rate"), (0.1, RATE_MAX)),
    **dict.fromkeys(_keys("realtime", "state_timeout", "command_timeout"), (0.0, TIMEOUT_MAX)),
    ("can", "bitrate"): (10_000, 1_000_000),  # classical CAN (CanSettings)
    **dict.fromkeys(_keys("can", "node_left", "node_right"), (0, 63)),
    ("can", "heartbeat_timeout"): (0.0, TIMEOUT_MAX),
    ("zenoh", "robot_id"): (0, 2**31 - 1),
    ("sweep", "ts"): (TS_MIN, TS_MAX),
    **dict.fromkeys(_keys("sweep", "delay", "jitter"), (0.0, DELAY_MAX)),
    ("sweep", "seeds"): (1, SWEEP_SEEDS_MAX),
    **dict.fromkeys(_keys("faults", "state_drop_every", "command_drop_every"), (0, 2**31 - 1)),
    ("faults", "seed"): (0, SEED_MAX),
    **dict.fromkeys(_keys("faults", "feedback_delay", "feedback_jitter"), (0.0, DELAY_MAX)),
    ("faults", "feedback_loss"): (0.0, 1.0),
    ("faults", "drive_fault_node"): (0, 63),
    ("impair", "loss"): (0.0, 1.0),
    ("impair", "loss_every"): (0, 2**31 - 1),
    ("impair", "rate_bps"): (0.0, RATE_BPS_MAX),
}
_POSITIVE = (
    _keys("limits", *LIMIT_NAMES.values())
    | _keys("timing", "ts")
    | _keys("run", "duration")
    | _keys("plant", "step", "max_speed")
    | _keys("disturbance", "period")
    | _keys("realtime", "rate", "sensor_rate", "state_timeout", "command_timeout")
    | _keys("robot", "mass", "yaw_inertia", "wheel_radius", "half_track", "gear_ratio")
    | _keys("can", "bitrate", "heartbeat_timeout")
    | _keys("sweep", "seeds")
)
_NON_NEGATIVE = (
    _keys("timing", "delay", "jitter")
    | _keys("plant", "lag", "noise_std", "quantization")
    | _keys("disturbance", "s1", "s2", "freq")
    | _keys("sweep", "ts", "delay", "jitter")
    | _keys("faults", *(f.name for f in dataclasses.fields(FaultsConfig)))  # every [faults] key
    | _keys("can", "watchdog_timeout")
    | _keys("impair", "loss", "loss_every", "rate_bps")
)
_FIVE = {("plant", "noise_std"), ("plant", "quantization")}
# (table, key) -> the numbers of values a list may have
_LENGTHS = {("plant", "friction"): (2,), ("plant", "max_speed"): (0, 2)}
# [disturbance] keys each kind reads; any other key must keep its default (a value1 in a sine
# table would be silently ignored otherwise).
_DISTURBANCE_KEYS = {
    "none": ("kind", "s1", "s2"),
    "constant": ("kind", "s1", "s2", "value1", "value2"),
    "sine": ("kind", "s1", "s2", "amplitude1", "amplitude2", "freq", "phase"),
    "random": ("kind", "s1", "s2", "period", "seed"),
}


# a field's annotation -> the TOML values it takes, as its errors name them
_TYPES: dict[str, tuple[Any, str]] = {
    "float": (int | float, "a number"),
    "int": (int, "an integer"),
    "str": (str, "a string"),
    "list": (list, "a list"),
}


def _coerce(table: str, key: str, annotation: str, value: Any) -> Any:
    where = f"[{table}] {key}"
    base = annotation.replace(" | None", "")
    kind = "list" if base.startswith("tuple[") else base
    types, name = _TYPES[kind]
    if isinstance(value, bool) or not isinstance(value, types):
        raise BadInputError(f"{where} must be {name}, got {type_name(value)} {value!r}")
    if kind == "float":
        value = float(value)
        if not math.isfinite(value):
            raise BadInputError(f"{where} must be finite, got {value!r}")
    elif kind == "str":
        plain_string(where, value)
    elif kind == "list":
        item = "str" if "str" in base else "float"
        return tuple(_coerce(table, f"{key}[{i}]", item, v) for i, v in enumerate(value))
    return value


def _check(table: str, key: str, value: Any) -> None:
    where = f"[{table}] {key}"
    if (table, key) in _CHOICES:
        choice(where, value, _CHOICES[table, key])
    many = isinstance(value, tuple)
    values = value if many else (value,)
    if (table, key) in _FIVE and len(values) != 5:
        raise BadInputError(f"{where} needs 5 values (x, y, theta, v, omega), got {len(values)}")
    lengths = _LENGTHS.get((table, key))
    if lengths is not None and len(values) not in lengths:
        raise BadInputError(f"{where} needs 2 values (v, omega), got {len(values)}")
    positive = (table, key) in _POSITIVE
    non_negative = (table, key) in _NON_NEGATIVE
    low, high = _RANGES.get((table, key), (-MAX_MAGNITUDE, MAX_MAGNITUDE))
    for i, v in enumerate(values):
        if v is None or isinstance(v, str):
            continue
        item = f"{where}[{i}]" if many else where
        if positive and not v > 0:
            raise BadInputError(f"{item} must be > 0, got {v!r}")
        if non_negative and v < 0:
            raise BadInputError(f"{item} must be >= 0, got {v!r}")
        if not low <= v <= high:
            raise BadInputError(f"{item} must be {describe(low, high, positive)}, got {v!r}")


def _parse_table(name: str, raw: Any) -> Any:
    cls = _TABLES[name]
    if not isinstance(raw, Mapping):
        raise BadInputError(f"[{name}] must be a table, got {type_name(raw)} {raw!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(map(str, set(raw) - set(fields)))
    if unknown:
        raise BadInputError(
            f"[{name}]: unknown key(s) {', '.join(unknown)} (allowed: {', '.join(fields)})"
        )
    values: Toml = {}
    for key, value in raw.items():  # every table's annotations are strings (__future__)
        values[key] = _coerce(name, key, fields[key].type, value)
        _check(name, key, values[key])
    return cls(**values)


def parse_scenario(data: Mapping[str, Any], base_dir: Path, source: str = "") -> Scenario:
    """A :class:`Scenario` from the parsed TOML ``data`` (BadInputError names any bad key)."""
    allowed = {*_TABLES, "reference", "controller", "provenance"}
    unknown = sorted(map(str, set(data) - allowed))
    if unknown:
        names = ", ".join(f"[{k}]" if isinstance(data[k], Mapping) else k for k in unknown)
        what = "table" if all(isinstance(data[k], Mapping) for k in unknown) else "top-level key"
        raise BadInputError(
            f"{names}: unknown {what}{'s' if len(unknown) > 1 else ''} "
            f"(allowed tables: {', '.join(sorted(allowed - {'provenance'}))})"
        )
    for required in ("reference", "initial"):
        if required not in data:
            raise BadInputError(f"[{required}]: missing table (it is required)")
    for name in ("reference", "controller"):
        if name in data and not isinstance(data[name], Mapping):
            raise BadInputError(
                f"[{name}] must be a table, got {type_name(data[name])} {data[name]!r}"
            )
    parsed = {name: _parse_table(name, data[name]) for name in _TABLES if name in data}
    controller = dict(data.get("controller", {}))
    controller.setdefault("law", "unified")
    try:
        check_reference(data["reference"])
        check_controller(controller)
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    scenario = Scenario(
        reference=dict(data["reference"]),
        controller=controller,
        base_dir=base_dir,
        source=source,
        **parsed,
    )
    _check_across(scenario)
    return scenario


def _check_across(scenario: Scenario) -> None:
    """The checks that need more than one key (BadInputError names them)."""
    t = scenario.timing
    if t.jitter_kind == "replay":
        if not t.replay.strip():
            raise BadInputError("[timing] replay: jitter_kind = 'replay' needs a latency file path")
        head = t.replay.rpartition("::")[0] if "::" in t.replay else t.replay
        if not head.strip():
            raise BadInputError(f"[timing] replay: no path before '::' in {t.replay!r}")
    elif t.replay:
        raise BadInputError(
            f"[timing] replay = {t.replay!r} is read only with jitter_kind = 'replay' "
            f"(jitter_kind is {t.jitter_kind!r})"
        )
    d = scenario.disturbance
    default = Disturbance()
    for key in (f.name for f in dataclasses.fields(Disturbance)):
        if key not in _DISTURBANCE_KEYS[d.kind] and getattr(d, key) != getattr(default, key):
            raise BadInputError(
                f"[disturbance] {key}: not read by kind = {d.kind!r} (its keys: "
                f"{', '.join(_DISTURBANCE_KEYS[d.kind][1:])})"
            )
    b1, b2 = max_abs(d)
    if b1 > d.s1 * (1 + _REL_TOL) or b2 > d.s2 * (1 + _REL_TOL):
        raise BadInputError(
            f"[disturbance] s1, s2: the {d.kind} disturbance reaches |d1| = {b1:g}, |d2| = {b2:g}, "
            f"beyond the declared bounds s1 = {d.s1:g}, s2 = {d.s2:g} of Assumption 1"
        )
    can = scenario.can
    plain_string("[can] interface", can.interface, empty=False)
    plain_string("[can] channel", can.channel, empty=False)
    if can.node_left == can.node_right:
        raise BadInputError(f"[can] node_left, node_right must differ, both are {can.node_left}")
    for i, endpoint in enumerate(scenario.zenoh.endpoints):
        locator(f"[zenoh] endpoints[{i}]", endpoint)
    check_loop_size(scenario)


def check_loop_size(
    scenario: Scenario,
    dur_name: str = "[run] duration",
    ts_name: str = "[timing] ts",
    duration: float | None = None,
    ts: float | None = None,
    ts_max: float | None = None,
) -> None:
    """Control samples of a ``duration`` s loop at ``ts`` (default: the scenario's) and plant
    steps per period (the longest, ``ts_max``, default ``ts``) within MAX_SAMPLES and
    MAX_SUBSTEPS (the simulator keeps one row per sample)."""
    duration = scenario.run.duration if duration is None else duration
    ts = scenario.timing.ts if ts is None else ts
    ts_max = ts if ts_max is None else ts_max
    samples, step = duration / ts, scenario.plant.step
    if samples > MAX_SAMPLES:
        raise BadInputError(
            f"{dur_name} = {duration:g} s at {ts_name} = {ts:g} s is {samples:.3g} control "
            f"samples, more than {MAX_SAMPLES:,}"
        )
    if step is not None and ts_max / step > MAX_SUBSTEPS:
        raise BadInputError(
            f"[plant] step = {step:g} s is {ts_max / step:.3g} plant steps per {ts_name} = "
            f"{ts_max:g} s, more than {MAX_SUBSTEPS:,}"
        )


def load_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file."""
    p = Path(path)
    try:
        text = p.read_bytes()
    except OSError as exc:
        raise BadInputError(f"cannot read scenario {p}: {exc.strerror or exc}") from exc
    try:
        data = tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise BadInputError(f"scenario {p} is not valid TOML: {exc}") from exc
    data = with_base(data, p.resolve().parent, (p.resolve(),))
    return parse_scenario(data, p.resolve().parent, str(p))


#: How deep ``base`` may chain (a scenario on a scenario on ...): a guard, not a design limit.
BASE_DEPTH_MAX = 8


def with_base(data: Mapping[str, Any], base_dir: Path, chain: tuple[Path, ...] = ()) -> Toml:
    """``data`` on top of the scenario its top-level ``base`` names (docs/scenario.md,
    "Starting from another scenario"): the base's tables, each key the file sets replacing the
    base's; [reference] and [controller] replaced whole when the file names another ``kind`` or
    ``law`` (the other's keys would not fit). ``base`` is a scenario file (relative to this
    one's folder) or a bundled scenario's name, and may have a base itself."""
    if "base" not in data:
        return dict(data)
    name = data["base"]
    if not isinstance(name, str) or not name.strip():
        raise BadInputError(
            f"base must be a scenario file or a bundled scenario's name, got "
            f"{type_name(name)} {name!r}"
        )
    nearby = base_dir / name
    try:
        path = (nearby if nearby.is_file() else resolve_scenario(name)).resolve()
    except BadInputError as exc:
        raise BadInputError(f"base = {name!r}: {exc}") from exc
    if path in chain:
        raise BadInputError(f"base = {name!r}: {path.name} starts from itself (a cycle)")
    if len(chain) > BASE_DEPTH_MAX:
        raise BadInputError(f"base = {name!r}: more than {BASE_DEPTH_MAX} bases in a chain")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise BadInputError(f"base = {name!r}: {path} cannot be read as TOML: {exc}") from exc
    merged = with_base(raw, path.parent, (*chain, path))
    merged.pop("provenance", None)  # the base's own record, not this scenario's
    for key, value in data.items():
        if key == "base":
            continue
        below = merged.get(key)
        if (
            isinstance(value, Mapping)
            and isinstance(below, Mapping)
            and not _replaces(key, below, value)
        ):
            merged[key] = {**below, **value}
        else:
            merged[key] = value
    return merged


def _replaces(table: str, below: Mapping[str, Any], own: Mapping[str, Any]) -> bool:
    """Whether ``own`` replaces the base's table whole: another reference kind or law."""
    what = {"reference": ("kind", None), "controller": ("law", "unified")}.get(table)
    if what is None or what[0] not in own:
        return False
    return own[what[0]] != below.get(what[0], what[1])


def loads_scenario(text: str, base_dir: Path | None = None) -> Scenario:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BadInputError(f"scenario is not valid TOML: {exc}") from exc
    return parse_scenario(with_base(data, base_dir or Path.cwd()), base_dir or Path.cwd())


def build_reference(scenario: Scenario) -> Any:
    """The scenario's virtual robot (3); its errors become BadInputError."""
    try:
        return _build(scenario.reference, scenario.base_dir)
    except (ValueError, OSError) as exc:
        raise BadInputError(str(exc)) from exc


# Where each symbol of the design conditions is set (DesignError names conditions, not keys).
_SYMBOL_KEYS = {
    **dict.fromkeys(LIMIT_NAMES.values(), "limits"),
    **{k: "disturbance" for k in ("s1", "s2")},
    **{k: "reference" for k in ("mu1", "mu2", "k1", "k2")},
    **{k: "controller" for k in ("m1", "m2", "l1", "l2", "lam", "rho", "eps1", "eps2")},
}
_SYMBOL = re.compile(r"\b(" + "|".join(_SYMBOL_KEYS) + r")\b")


def design_message(exc: Any) -> str:
    """A broken design condition (controller_service.design.DesignError) as one line that
    names the keys it involves: ``[controller] m1 = 3 breaks (9) m1 < phi1 - mu1 ...``."""
    condition = str(getattr(exc, "condition", ""))
    symbols = list(dict.fromkeys(_SYMBOL.findall(condition)))
    if not symbols:
        return str(exc)
    subject, others = symbols[0], symbols[1:]
    value, bound = float(exc.value), float(exc.bound)
    if condition.endswith("> 0") or ">= 0" in condition:
        value = -value  # "x > 0" is checked as -x < 0
    where = f"[{_SYMBOL_KEYS[subject]}] {subject}"
    text = f"{where} = {value:.6g} breaks design condition {condition} (bound {bound:.6g})"
    if others:
        text += "; it also involves " + ", ".join(f"[{_SYMBOL_KEYS[k]}] {k}" for k in others)
    if _SYMBOL_KEYS[subject] == "reference":
        text += f" ({subject} defaults to the reference's own maximum)"
    return text


def design_context(scenario: Scenario, reference: Any) -> DesignContext:
    """The DesignContext: limits (2), s1, s2 of Assumption 1 and mu1..k2 of Assumption 2 (by
    default the reference's own maxima; given ones must not be exceeded by the reference)."""
    bounds: dict[str, float] = {}
    table = scenario.reference
    kind = table.get("kind", "?")
    for key in ("mu1", "mu2", "k1", "k2"):
        own = float(getattr(reference, key))
        given = table.get(key, own)
        if isinstance(given, bool) or not isinstance(given, int | float):
            raise BadInputError(f"[reference] {key} must be a number, got {given!r}")
        bounds[key] = given = float(given)
        if key in table and own > given * (1 + _REL_TOL) + 1e-15:
            raise BadInputError(
                f"[reference] {key} = {given:g} is below the {kind} reference's own "
                f"maximum {own:g} (Assumption 2 needs the bound to hold)"
            )
    d = scenario.disturbance
    return DesignContext(limits=scenario.limits, s1=d.s1, s2=d.s2, **bounds)


def build_loop(scenario: Scenario) -> tuple[Any, Any, DesignContext]:
    """(controller, reference, context) for the scenario; design errors become BadInputError."""
    reference = build_reference(scenario)
    context = design_context(scenario, reference)
    try:
        law_path = law_path_for(scenario.base_dir)
        controller = build_controller(dict(scenario.controller), context, law_path)
    except DesignError as exc:
        raise BadInputError(design_message(exc)) from exc
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    return controller, reference, context


def _table_dict(value: Any) -> Toml:
    if isinstance(value, Mapping):  # [reference] and [controller], as given
        return dict(value)
    pairs = ((f.name, getattr(value, f.name)) for f in dataclasses.fields(value))
    return {name: list(v) if isinstance(v, tuple) else v for name, v in pairs}


# scenario.resolved.toml's tables, in order ([impair] only when given: it moves a run into a
# network namespace)
_WRITTEN = (
    "limits", "disturbance", "reference", "initial", "controller", "plant", "timing", "run",
    "robot", "realtime", "can", "zenoh", "sweep", "faults", "impair",
)  # fmt: skip


def scenario_dict(scenario: Scenario) -> Toml:
    """Every table of the scenario with every default filled in (a TOML-ready dict)."""
    tables = ((name, getattr(scenario, name)) for name in _WRITTEN)
    out = {name: _table_dict(table) for name, table in tables if table is not None}
    out["plant"]["step"] = scenario.plant_step
    return out


def resolved_dict(
    scenario: Scenario,
    controller: Any,
    context: DesignContext | None = None,
    extra_provenance: Mapping[str, Any] | None = None,
) -> Toml:
    """scenario.resolved.toml: every default filled (auto lam/rho resolved) plus [provenance]."""
    out = scenario_dict(scenario)
    out["controller"] = {**dict(scenario.controller), **resolved_controller_table(controller)}
    if context is not None:  # out["reference"] is scenario_dict's own copy
        out["reference"].update({k: getattr(context, k) for k in ("mu1", "mu2", "k1", "k2")})
    t, d, p = scenario.timing, scenario.disturbance, scenario.plant
    prov = provenance({"timing": t.seed, "disturbance": d.seed, "sensor": p.noise_seed})
    prov["schema_version"] = SCHEMA_VERSION
    if scenario.source:
        prov["scenario_file"] = scenario.source
    if extra_provenance:
        prov.update(extra_provenance)
    out["provenance"] = prov
    return out

"""Scenario files (CONTRACT.md, documented key by key in docs/scenario.md).

One TOML file describes one closed loop. Every table is optional except [reference] and
[initial]; defaults are the paper's Section 4 set-up. Unknown tables or keys and wrong types are
refused with :class:`hil.errors.BadInputError` naming the key (exit 2). The [reference] and
[controller] tables are kept as plain dicts and validated by the builders that own them
(:func:`controller_service.references.build_reference`,
:func:`controller_service.registry.build_controller`).
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller_service.laws.base import DesignContext, Limits
from hil.errors import BadInputError
from hil.provenance import provenance
from plant_emulator.disturbances import KINDS as DISTURBANCE_KINDS
from plant_emulator.disturbances import Disturbance, max_abs
from plant_emulator.sensors import Sensor
from protocol.can.bus_factory import CanSettings
from protocol.can.wheel_mapping import RobotGeometry

SCHEMA_VERSION = 1
JITTER_KINDS = ("uniform", "normal", "replay")
_REL_TOL = 1e-12


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
    """[plant]: RK4 step (None = ts/10), sensor noise and quantization, actuator lag."""

    step: float | None = None
    noise_std: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    noise_seed: int = 0
    quantization: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    lag: float = 0.0


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
class RobotConfig:
    """[robot]: the physical robot behind the unit-mass model (1), for the CAN wheel mapping."""

    # Defaults are protocol.can.wheel_mapping.RobotGeometry's.
    mass: float = RobotGeometry.mass
    yaw_inertia: float = RobotGeometry.yaw_inertia
    wheel_radius: float = RobotGeometry.wheel_radius
    half_track: float = RobotGeometry.half_track
    gear_ratio: float = RobotGeometry.gear_ratio


@dataclass(frozen=True)
class RealtimeConfig:
    rate: float | None = None
    sensor_rate: float | None = None
    trigger: str = "periodic"
    state_timeout: float = 0.05
    command_timeout: float = 0.05
    scheduling: str = "other"


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
class FaultsConfig:
    """[faults]: fault injection on the wire (0 = off). The plant does not publish the State
    with seq % n == n - 1 (n = state_drop_every), the controller does not publish on Zenoh the
    TorqueCommand with cmd_seq % m == m - 1 (m = command_drop_every); both log each drop as
    injected. ``seed`` is reserved for random faults."""

    state_drop_every: int = 0
    command_drop_every: int = 0
    seed: int = 0


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
        return Sensor(
            tuple(self.plant.noise_std), tuple(self.plant.quantization), self.plant.noise_seed
        )  # type: ignore[arg-type]

    def with_overrides(self, duration: float | None = None, ts: float | None = None) -> Scenario:
        """The same scenario with a new run duration and/or control period (command line)."""
        out = self
        if duration is not None:
            if not (duration > 0.0 and math.isfinite(duration)):
                raise BadInputError(f"--duration must be > 0, got {duration}")
            out = dataclasses.replace(out, run=RunConfig(float(duration)))
        if ts is not None:
            if not (ts > 0.0 and math.isfinite(ts)):
                raise BadInputError(f"--ts must be > 0, got {ts}")
            out = dataclasses.replace(out, timing=dataclasses.replace(out.timing, ts=float(ts)))
        return out


# table name -> (dataclass, constraints)
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
}
_CHOICES: dict[tuple[str, str], tuple[str, ...]] = {
    ("disturbance", "kind"): DISTURBANCE_KINDS,
    ("timing", "jitter_kind"): JITTER_KINDS,
    ("realtime", "trigger"): ("periodic", "on_state"),
    ("realtime", "scheduling"): ("fifo", "other"),
    ("zenoh", "mode"): ("peer", "client", "router"),
}
_POSITIVE = {("limits", k) for k in ("phi1", "phi2", "varpi1", "varpi2")} | {
    ("timing", "ts"),
    ("run", "duration"),
    ("plant", "step"),
    ("disturbance", "period"),
    ("realtime", "rate"),
    ("realtime", "sensor_rate"),
    ("realtime", "state_timeout"),
    ("realtime", "command_timeout"),
    ("robot", "mass"),
    ("robot", "yaw_inertia"),
    ("robot", "wheel_radius"),
    ("robot", "half_track"),
    ("robot", "gear_ratio"),
    ("can", "bitrate"),
    ("can", "heartbeat_timeout"),
    ("sweep", "seeds"),
}
_NON_NEGATIVE = {
    ("timing", "delay"),
    ("timing", "jitter"),
    ("plant", "lag"),
    ("disturbance", "s1"),
    ("disturbance", "s2"),
    ("disturbance", "freq"),
    ("plant", "noise_std"),
    ("plant", "quantization"),
    ("sweep", "ts"),
    ("sweep", "delay"),
    ("sweep", "jitter"),
    ("faults", "state_drop_every"),
    ("faults", "command_drop_every"),
    ("faults", "seed"),
    ("can", "watchdog_timeout"),
}
_FIVE = {("plant", "noise_std"), ("plant", "quantization")}


def _type_name(v: Any) -> str:
    return {bool: "boolean", int: "integer", float: "number", str: "string"}.get(
        type(v), type(v).__name__
    )


def _coerce(table: str, key: str, annotation: str, value: Any) -> Any:
    where = f"[{table}] {key}"
    base = annotation.replace(" | None", "")
    if base == "float":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise BadInputError(f"{where} must be a number, got {_type_name(value)} {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise BadInputError(f"{where} must be finite, got {value!r}")
        return value
    if base == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise BadInputError(f"{where} must be an integer, got {_type_name(value)} {value!r}")
        return value
    if base == "str":
        if not isinstance(value, str):
            raise BadInputError(f"{where} must be a string, got {_type_name(value)} {value!r}")
        return value
    if base.startswith("tuple["):
        if not isinstance(value, list):
            raise BadInputError(f"{where} must be a list, got {_type_name(value)} {value!r}")
        item = "str" if "str" in base else "float"
        return tuple(_coerce(table, f"{key}[{i}]", item, v) for i, v in enumerate(value))
    raise AssertionError(annotation)  # pragma: no cover - the dataclasses above are closed


def _check(table: str, key: str, value: Any) -> None:
    where = f"[{table}] {key}"
    choices = _CHOICES.get((table, key))
    if choices is not None and value not in choices:
        allowed = ", ".join(map(repr, choices))
        raise BadInputError(f"{where} must be one of {allowed}, got {value!r}")
    values = value if isinstance(value, tuple) else (value,)
    if (table, key) in _POSITIVE and any(v is not None and not v > 0 for v in values):
        raise BadInputError(f"{where} must be > 0, got {value!r}")
    if (table, key) in _NON_NEGATIVE and any(v is not None and v < 0 for v in values):
        raise BadInputError(f"{where} must be >= 0, got {value!r}")
    if (table, key) in _FIVE and len(values) != 5:
        raise BadInputError(f"{where} needs 5 values (x, y, theta, v, omega), got {len(values)}")


def _parse_table(name: str, raw: Any) -> Any:
    cls = _TABLES[name]
    if not isinstance(raw, Mapping):
        raise BadInputError(f"[{name}] must be a table, got {_type_name(raw)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        raise BadInputError(
            f"[{name}]: unknown key(s) {', '.join(unknown)} (allowed: {', '.join(fields)})"
        )
    values: dict[str, Any] = {}
    for key, value in raw.items():
        annotation = fields[key].type if isinstance(fields[key].type, str) else "float"
        coerced = _coerce(name, key, str(annotation), value)
        _check(name, key, coerced)
        values[key] = coerced
    return cls(**values)


def parse_scenario(data: Mapping[str, Any], base_dir: Path, source: str = "") -> Scenario:
    """A :class:`Scenario` from the parsed TOML ``data`` (BadInputError names any bad key)."""
    allowed = {*_TABLES, "reference", "controller", "provenance"}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise BadInputError(
            f"unknown table(s) or key(s) {', '.join(unknown)} "
            f"(allowed tables: {', '.join(sorted(allowed - {'provenance'}))})"
        )
    for required in ("reference", "initial"):
        if required not in data:
            raise BadInputError(f"missing table [{required}] (it is required)")
    for name in ("reference", "controller"):
        if name in data and not isinstance(data[name], Mapping):
            raise BadInputError(f"[{name}] must be a table")
    kwargs: dict[str, Any] = {
        name: _parse_table(name, data[name]) for name in _TABLES if name in data
    }
    if "initial" not in kwargs:
        kwargs["initial"] = Initial()
    controller = dict(data.get("controller", {}))
    controller.setdefault("law", "unified")
    scenario = Scenario(
        reference=dict(data["reference"]),
        controller=controller,
        base_dir=base_dir,
        source=source,
        **kwargs,
    )
    t = scenario.timing
    if t.jitter_kind == "replay" and not t.replay:
        raise BadInputError("[timing] replay: jitter_kind = 'replay' needs a latency file path")
    d = scenario.disturbance
    b1, b2 = max_abs(d)
    if b1 > d.s1 * (1 + _REL_TOL) or b2 > d.s2 * (1 + _REL_TOL):
        raise BadInputError(
            f"[disturbance] s1, s2: the {d.kind} disturbance reaches |d1| = {b1:g}, |d2| = {b2:g}, "
            f"beyond the declared bounds s1 = {d.s1:g}, s2 = {d.s2:g} of Assumption 1"
        )
    return scenario


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
    return parse_scenario(data, p.resolve().parent, str(p))


def loads_scenario(text: str, base_dir: Path | None = None) -> Scenario:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BadInputError(f"scenario is not valid TOML: {exc}") from exc
    return parse_scenario(data, base_dir or Path.cwd())


def build_reference(scenario: Scenario) -> Any:
    """The scenario's virtual robot (3); its errors become BadInputError."""
    from controller_service.references import build_reference as _build

    try:
        return _build(scenario.reference, scenario.base_dir)
    except (ValueError, OSError) as exc:
        raise BadInputError(str(exc)) from exc


def design_context(scenario: Scenario, reference: Any) -> DesignContext:
    """The DesignContext: limits (2), s1, s2 of Assumption 1 and mu1..k2 of Assumption 2.

    mu1, mu2, k1, k2 default to the reference's own maxima; given ones must not be exceeded by
    the reference (checked here, naming the key).
    """
    bounds: dict[str, float] = {}
    table = scenario.reference
    kind = table.get("kind", "?")
    for key in ("mu1", "mu2", "k1", "k2"):
        own = float(getattr(reference, key))
        if key in table:
            given = table[key]
            if isinstance(given, bool) or not isinstance(given, int | float):
                raise BadInputError(f"[reference] {key} must be a number, got {given!r}")
            given = float(given)
            if own > given * (1 + _REL_TOL) + 1e-15:
                raise BadInputError(
                    f"[reference] {key} = {given:g} is below the {kind} reference's own "
                    f"maximum {own:g} (Assumption 2 needs the bound to hold)"
                )
            bounds[key] = given
        else:
            bounds[key] = own
    d = scenario.disturbance
    return DesignContext(limits=scenario.limits, s1=d.s1, s2=d.s2, **bounds)


def build_loop(scenario: Scenario) -> tuple[Any, Any, DesignContext]:
    """(controller, reference, context) for the scenario; design errors become BadInputError."""
    from controller_service.registry import build_controller

    reference = build_reference(scenario)
    context = design_context(scenario, reference)
    try:
        controller = build_controller(dict(scenario.controller), context)
    except ValueError as exc:
        raise BadInputError(str(exc)) from exc
    return controller, reference, context


def _table_dict(value: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in dataclasses.fields(value):
        v = getattr(value, f.name)
        out[f.name] = list(v) if isinstance(v, tuple) else v
    return out


def scenario_dict(scenario: Scenario) -> dict[str, Any]:
    """Every table of the scenario with every default filled in (a TOML-ready dict)."""
    out: dict[str, Any] = {
        "limits": _table_dict(scenario.limits),
        "disturbance": _table_dict(scenario.disturbance),
        "reference": dict(scenario.reference),
        "initial": _table_dict(scenario.initial),
        "controller": dict(scenario.controller),
    }
    for name in (
        "plant",
        "timing",
        "run",
        "robot",
        "realtime",
        "can",
        "zenoh",
        "sweep",
        "faults",
    ):
        out[name] = _table_dict(getattr(scenario, name))
    out["plant"]["step"] = scenario.plant_step
    return out


def resolved_dict(
    scenario: Scenario,
    controller: Any,
    context: DesignContext | None = None,
    extra_provenance: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """scenario.resolved.toml: every default filled (auto lam/rho resolved) plus [provenance]."""
    from controller_service.registry import resolved_controller_table

    out = scenario_dict(scenario)
    out["controller"] = {**dict(scenario.controller), **resolved_controller_table(controller)}
    if context is not None:
        ref = dict(out["reference"])
        for key in ("mu1", "mu2", "k1", "k2"):
            ref[key] = getattr(context, key)
        out["reference"] = ref
    seeds = {
        "timing": scenario.timing.seed,
        "disturbance": scenario.disturbance.seed,
        "sensor": scenario.plant.noise_seed,
    }
    prov = provenance(seeds)
    prov["schema_version"] = SCHEMA_VERSION
    if scenario.source:
        prov["scenario_file"] = scenario.source
    if extra_provenance:
        prov.update(extra_provenance)
    out["provenance"] = prov
    return out

"""Build the two services' cores and edges from the scenario (via :mod:`hil.scenario`).

The controller and the plant are rebuilt in their own processes from the same scenario file
and :class:`protocol.settings.RunSettings`, with the same builders the offline simulator uses,
so lockstep can equal the simulation bit for bit.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any

from controller_service.service import ControlCore
from plant_emulator.dynamics import Extremes, PlantState
from plant_emulator.sensors import Sensor
from plant_emulator.service import PlantCore
from protocol.settings import RunSettings


def load(settings: RunSettings) -> Any:
    from hil.scenario import load_scenario

    sc = load_scenario(settings.scenario_path)
    return sc.with_overrides(duration=settings.duration, ts=settings.ts)


def initial_memory(controller: Any, scenario: Any) -> Any:
    """The law's memory at t = 0 with z1(0), z2(0) of [initial] when the law takes them."""
    params = inspect.signature(controller.initial_memory).parameters
    if "z1" in params and "z2" in params:
        return controller.initial_memory(None, z1=scenario.initial.z1, z2=scenario.initial.z2)
    return controller.initial_memory(None)


def build_control_core(settings: RunSettings) -> tuple[ControlCore, str]:
    from hil.scenario import build_loop

    sc = load(settings)
    controller, reference, _context = build_loop(sc)
    core = ControlCore(
        controller,
        reference,
        settings.ts,
        sc.limits,
        memory=initial_memory(controller, sc),
    )
    law = str(sc.controller.get("law", getattr(controller, "name", "unified")))
    return core, law


def build_plant(settings: RunSettings) -> tuple[PlantCore, Sensor]:
    sc = load(settings)
    i = sc.initial
    core = PlantCore(
        PlantState(i.x, i.y, i.theta, i.v, i.omega, 0.0, 0.0),
        h=sc.plant_step,
        limits=sc.limits,
        disturbance=sc.disturbance,
        lag=sc.plant.lag,
        seed=None,
        extremes=Extremes(),
    )
    from plant_emulator.dynamics import track_initial

    track_initial(core.extremes, core.state, sc.limits)
    return core, sc.sensor


def can_settings(settings: RunSettings) -> Any:
    """The run's ``[can]`` table parsed once: interface, channel, node ids, heartbeat timeout."""
    from protocol.can.bus_factory import CanSettings

    return CanSettings.from_table(dict(settings.can))


def motor_limit(settings: RunSettings, limits: Any) -> tuple[Any, float]:
    """The robot's wheel geometry and the largest motor torque that (2)'s varpi1, varpi2 allow."""
    from protocol.can.wheel_mapping import RobotGeometry, motor_torque_limit

    geom = RobotGeometry(**settings.robot)
    return geom, motor_torque_limit(geom, limits.varpi1, limits.varpi2)


def open_can_bus(settings: RunSettings) -> Any:
    """The run's CAN bus, or None when CAN is neither applied nor live as a shadow."""
    if not (settings.can_live or settings.cmd_path == "can"):
        return None
    from protocol.can.bus_factory import open_bus

    cs = can_settings(settings)
    extra: dict[str, Any] = {}
    if cs.interface == "zenoh_can":
        extra["endpoint"] = settings.can_endpoint
    return open_bus(cs, **extra)


def effective_can_table(scenario: Any, interface: str | None = None) -> dict[str, Any]:
    """[can] as the run uses it. python-can's ``virtual`` bus is in-process only, so between
    the two processes it is replaced by ``zenoh_can`` (loopback, no kernel CAN needed)."""
    t = dataclasses.asdict(scenario.can)
    if interface:
        t["interface"] = interface
    if t["interface"] == "virtual":
        t["interface"] = "zenoh_can"
        t["channel"] = "hil0"
    return t


def check_can_interface(name: str, where: str) -> None:
    """``name`` must be an interface python-can knows (its own and plug-ins such as zenoh_can);
    checked before a run starts its services, which would fail opening the bus."""
    import can.interfaces

    from hil.errors import BadInputError

    known = sorted(can.interfaces.VALID_INTERFACES)
    if name not in known:
        raise BadInputError(
            f"{where} {name!r} is not a python-can interface (known: {', '.join(known)})"
        )


def robot_id_of(scenario: Any) -> str:
    rid = scenario.zenoh.robot_id
    return rid if isinstance(rid, str) else f"robot{rid}"


def lockstep_offsets(settings: RunSettings, n: int, h: float) -> list[int]:
    """Landing offsets (plant steps after each sample) drawn exactly as the simulator does."""
    from hil.sim.core import _replay
    from hil.sim.timing import extra_delays, landing_offsets

    sc = load(settings)
    t = sc.timing
    extra = extra_delays(t.jitter_kind, t.jitter, t.seed, n, _replay(sc))
    return [int(v) for v in landing_offsets(extra, t.delay, h).tolist()]

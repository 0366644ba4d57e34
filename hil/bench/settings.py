"""The scenario resolved into the services' settings (:class:`protocol.settings.RunSettings`).

``hil`` is the only reader of scenario files: here the checked :class:`hil.scenario.Scenario`
(with its command-line overrides) becomes the one file the services build from. Rates in Hz
(``[realtime] rate``, ``--rate``) become periods in seconds here, once.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import can.interfaces

from controller_service.registry import law_path_for
from hil.errors import BadInputError
from hil.folder.replay import RunLatencies, jitter_samples_from
from hil.provenance import Toml
from plant_emulator.drive_plant import bench_drive_settings
from protocol.settings import RunSettings

GEOMETRY_KEYS = ("mass", "yaw_inertia", "wheel_radius", "half_track", "gear_ratio")
# Copied as they are from the scenario's [realtime] and [timing] tables, and its tables of values.
REALTIME_KEYS = ("trigger", "tick_phase", "state_timeout", "command_timeout", "scheduling", "idle")
TIMING_KEYS = ("delay", "jitter", "jitter_kind", "seed")
TABLES = ("limits", "initial", "disturbance", "faults")
DESIGN_KEYS = ("s1", "s2", "mu1", "mu2", "k1", "k2")  # of the design context


def effective_can_table(scenario: Any, interface: str | None = None) -> Toml:
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
    known = sorted(can.interfaces.VALID_INTERFACES)
    if name not in known:
        raise BadInputError(
            f"{where} {name!r} is not a python-can interface (known: {', '.join(known)})"
        )


def drive_settings_of(scenario: Any) -> dict[str, float]:
    """What the bench sets on its virtual ODrives for this scenario's robot and limits (the
    rest is the firmware's): written into the run's settings, read by the plant."""
    return bench_drive_settings(scenario.robot, scenario.limits)


def robot_id_of(scenario: Any) -> str:
    rid = scenario.zenoh.robot_id
    return rid if isinstance(rid, str) else f"robot{rid}"


def replay_latencies(
    scenario: Any, run_latencies: RunLatencies | None = None
) -> list[float] | None:
    """``[timing] replay``'s latencies, read here so a bad file fails early; None: seeded jitter.
    ``run_latencies``: the reader of a real run's (the analysis's, which the bench does not
    import: the command hands it over, :func:`hil.analysis.replay.latencies_from_run`)."""
    t = scenario.timing
    if t.jitter_kind != "replay":
        return None
    return [float(v) for v in jitter_samples_from(scenario.base_dir / t.replay, run_latencies)]


def scenario_settings(scenario: Any, context: Any = None, **run: Any) -> RunSettings:
    """The settings of ``scenario`` (with its command-line overrides) and of the design
    ``context`` (None: the defaults, for a plant alone); ``run`` sets the run's own fields."""
    plant = scenario.plant
    timing = scenario.timing
    values: dict[str, Any] = {
        "scenario_path": str(scenario.source),
        "robot_id": robot_id_of(scenario),
        "duration": float(scenario.run.duration),
        "ts": float(timing.ts),
        "sensor_ts": float(timing.ts),
        **{k: getattr(scenario.realtime, k) for k in REALTIME_KEYS},
        "can": effective_can_table(scenario),
        "robot": {k: getattr(scenario.robot, k) for k in GEOMETRY_KEYS},
        "drives": drive_settings_of(scenario),
        "zenoh_mode": scenario.zenoh.mode,
        "controller": dict(scenario.controller),
        "reference": dict(scenario.reference),
        "base_dir": str(scenario.base_dir.resolve()),
        "law_path": list(law_path_for(scenario.base_dir)),
        **{k: dataclasses.asdict(getattr(scenario, k)) for k in TABLES},
        "plant_step": scenario.plant_step,
        "lag": plant.lag,
        "friction": list(plant.friction),
        "max_speed": list(plant.max_speed),
        "sensor": {
            "noise_std": list(plant.noise_std),
            "quantization": list(plant.quantization),
            "seed": plant.noise_seed,
        },
        **{k: getattr(timing, k) for k in TIMING_KEYS},
        "replay": run.pop("replay") if "replay" in run else replay_latencies(scenario),
    }
    if context is not None:
        values["design"] = {k: float(getattr(context, k)) for k in DESIGN_KEYS}
    values.update(run)
    return RunSettings(**values)

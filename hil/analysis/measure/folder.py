"""A run folder's measurement: made once from its hop logs, saved, and read back.

:func:`measure_and_save` is the one producer (``hil run`` and ``hil recover`` call it through
:func:`hil.analysis.analyze.analyze`; a folder written before series.npz existed gets it on first
read). Everything after the run reads :func:`measured` and computes no figure of its own.
"""

from __future__ import annotations

import contextlib
import tomllib
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

from hil.analysis.measure.device import DeviceLimits
from hil.analysis.measure.figures import Measurement, measure
from hil.analysis.measure.logs import RunLogs, load_folder_logs, load_recording_logs
from hil.folder import RunFolder, layout, read_series, write_series
from hil.folder.recording import read_attachments
from hil.folder.scenario_view import bound_inputs, bound_inputs_of, view_of
from hil.provenance import Toml
from hil.scenario import Scenario
from protocol.can.wheel_mapping import RobotGeometry, motor_torque_limit

# The drives' own torque limit leaves this much above the largest legal motor torque (the
# float32 a frame carries: plant_emulator.drive_plant.FLOAT32_HAIR); a frame within it is legal.
FLOAT32_HAIR = 1e-6


def device_limits(limits: Mapping[str, Any], robot: Mapping[str, Any]) -> DeviceLimits | None:
    """What a device's torques are judged against: [limits] varpi1, varpi2 and the largest
    motor torque they ask of one wheel of [robot] (None without the limits)."""
    try:
        varpi1, varpi2 = float(limits["varpi1"]), float(limits["varpi2"])
    except (KeyError, TypeError, ValueError):
        return None
    names = RobotGeometry.__dataclass_fields__
    try:
        g = RobotGeometry(**{k: float(v) for k, v in robot.items() if k in names})
        motor = motor_torque_limit(g, varpi1, varpi2) * (1.0 + FLOAT32_HAIR)
    except (TypeError, ValueError):
        motor = None
    return DeviceLimits(varpi1, varpi2, motor)


def resolved_scenario(folder: Path) -> Toml | None:
    try:
        return tomllib.loads((folder / layout.SCENARIO_RESOLVED).read_text())
    except (OSError, ValueError):
        return None


def measure_logs(logs: RunLogs, resolved: Toml | None) -> Measurement:
    bound = bound_inputs(resolved) if resolved is not None else None
    limits = (
        device_limits(resolved.get("limits") or {}, resolved.get("robot") or {})
        if resolved is not None
        else None
    )
    return measure(logs, bound, limits)


def measure_folder(folder: str | Path) -> Measurement | None:
    """The run folder's measurement from its hop logs (None when it has none: a simulation)."""
    folder = Path(folder)
    logs = load_folder_logs(folder)
    if logs is None:
        return None
    return measure_logs(logs, resolved_scenario(folder))


def measure_and_save(
    folder: Path, logs: RunLogs | None = None, scenario: Scenario | None = None
) -> Measurement | None:
    """Measure the folder's hop logs (``logs`` when already read) and save the series;
    ``scenario``: the folder's resolved scenario as the caller holds it (else read and parsed)."""
    logs = logs if logs is not None else load_folder_logs(folder)
    if logs is None or logs.plant is None:
        return None
    if scenario is not None:
        limits = device_limits(asdict(scenario.limits), asdict(scenario.robot))
        m = measure(logs, bound_inputs_of(view_of(scenario)), limits)
    else:
        m = measure_logs(logs, resolved_scenario(folder))
    # A read-only folder is still read; it is measured again next time.
    with contextlib.suppress(OSError):
        write_series(folder, m.arrays())
    return m


def measured(folder: RunFolder) -> Measurement | None:
    """The run's measurement as its folder holds it: summary.json's figures and the saved
    series (None for a simulation). A folder from before series.npz is measured once, here,
    by the same :func:`measure_and_save`; summary.json is never rewritten."""
    arrays = read_series(folder.path)
    if arrays is None:
        m = measure_and_save(folder.path)
        if m is None:
            return None
        arrays = m.arrays()
        if not isinstance(folder.summary.get("timing"), dict):
            return m  # a summary without figures: the measurement is all there is
    return Measurement.from_saved(folder.summary, arrays)


def measure_recording(path: str | Path) -> Measurement | None:
    """The same from a recording alone (its attached hop logs and resolved scenario)."""
    logs = load_recording_logs(path)
    if logs is None:
        return None
    toml = read_attachments(path, names=(layout.SCENARIO_RESOLVED,)).get(layout.SCENARIO_RESOLVED)
    return measure_logs(logs, tomllib.loads(toml.decode()) if toml is not None else None)

"""The measurement of a run folder (or a recording): hop logs + the resolved scenario."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from hil.measure.figures import BoundInputs, Measurement, measure
from hil.measure.logs import RunLogs, load_folder_logs, load_recording_logs

UNIFIED_LAWS = ("unified", "unified_boundary")


def bound_inputs(resolved: dict[str, Any]) -> BoundInputs | None:
    """The certificate's inputs from a resolved scenario (None: the law has no certificate)."""
    from types import SimpleNamespace

    from hil.report.scenario_view import view

    sv = view(resolved)
    if sv.law not in UNIFIED_LAWS:
        return None
    return BoundInputs(
        SimpleNamespace(**sv.controller), sv.context, sv.boundary_layer, sv.v0, sv.w0
    )


def resolved_scenario(folder: Path) -> dict[str, Any] | None:
    try:
        return tomllib.loads((folder / "scenario.resolved.toml").read_text())
    except (OSError, ValueError):
        return None


def measure_logs(logs: RunLogs, resolved: dict[str, Any] | None) -> Measurement:
    return measure(logs, bound_inputs(resolved) if resolved is not None else None)


def measure_folder(folder: str | Path) -> Measurement | None:
    """The run folder's measurement (None when it has no hop logs: a simulation folder)."""
    folder = Path(folder)
    logs = load_folder_logs(folder)
    if logs is None:
        return None
    return measure_logs(logs, resolved_scenario(folder))


def measure_recording(path: str | Path) -> Measurement | None:
    """The same from a recording alone (its attached hop logs and resolved scenario)."""
    from hil.recording import read_attachments

    logs = load_recording_logs(path)
    if logs is None:
        return None
    resolved = None
    toml = read_attachments(path, names=("scenario.resolved.toml",)).get("scenario.resolved.toml")
    if toml is not None:
        resolved = tomllib.loads(toml.decode())
    return measure_logs(logs, resolved)

"""The typed records a run folder holds (docs/run-folder.md): summary.json and its certificate;
and what the bench hands the analysis with the raw folder it wrote (:class:`Recorded`).

JSON objects on disk and dicts in memory (scripts read them as such); these TypedDicts say which
keys exist and what each holds, so that a reader and a type checker agree with the writer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

if TYPE_CHECKING:
    from controller_service.laws.base import DesignContext
    from hil.scenario import Scenario
    from protocol.settings import RunSettings


class Stall(TypedDict, total=False):
    t_s: float
    age_s: float
    cause: str
    owner: str


class Certificate(TypedDict, total=False):
    """The sampled-data certificate at the measured command age D (``hil.analysis.measure``), or at
    a simulation's D = Ts + worst delay (``hil.sim.certificate.scenario_certificate``)."""

    path: str | None  # the applied path, never a shadow
    d_max_s: float | None  # the command age D, on the plant's clock
    d_max_upper_s: float  # the largest D the CAN logs allow, when the matching is ambiguous
    d_star_s: float | None  # the largest D for which (2) is guaranteed (None: no bound)
    margin_s: float | None  # d_star_s - d_max_s
    held: bool | None  # None: unknown (ambiguous CAN matching)
    v_bound: float | None
    omega_bound: float | None
    failed_conditions: list[str]
    stall_threshold_s: float | None
    stall_count: int
    stalled_time_s: float
    stalls_by_owner: dict[str, int]
    d_system_s: float | None
    stalls: list[Stall]
    source: str
    error: str  # the design the certificate rejected, and why


class ControllerExit(TypedDict, total=False):
    """The controller process ended before the plant did (``hil run`` then stops the run at
    once): its exit code, or the signal that killed it, and when, in seconds from the run's
    epoch (as ``hil run`` saw it, within its 50 ms poll)."""

    code: int | None  # None: killed by a signal
    signal: str | None  # e.g. "SIGKILL"
    t_s: float | None
    law_fault: bool  # it exited because its law failed (law_fault.json)
    output: str  # its console output, relative to the run folder (controller.log)


class RunExtra(TypedDict, total=False):
    """What the bench adds to summary.json about the run itself, in this key order
    (:func:`hil.bench.lifecycle.run_extra`; a fleet's group, ``hil recover`` and [impair] add
    theirs): facts of the processes and the recorder, never a figure of the hop logs."""

    interrupted: bool
    error: str | None  # the run stopped by an error of its own (its services never ready)
    recovered: bool  # rebuilt by hil recover (hil.bench.repair)
    wall_time_s: float
    exit_codes: dict[str, int | None]  # each child process's, by name
    recording: str
    recorded_messages: int
    recorder: dict[str, Any]  # the taps' counts and the CAN socket's drops (hil.observe)
    secure: bool
    note: str
    shared_processes: dict[str, list[str]]  # a fleet's group: the robots of its processes
    controller_exit: ControllerExit  # absent: the controller outlived the plant
    impair: dict[str, Any]  # [impair]: the kernel's counts (hil.bench.impair)


@dataclass
class Recorded:
    """One robot's run as the bench leaves it: the raw folder it wrote and what the analysis
    (:func:`hil.analysis.analyze.analyze`) needs besides: the scenario and settings it ran, the
    reference and design context its controller ran with, and the run's own facts."""

    run_dir: Path
    scenario: Scenario
    settings: RunSettings
    reference: Any  # controller_service.references' reference of the scenario
    context: DesignContext
    extra: RunExtra


class Summary(TypedDict, total=False):
    """summary.json of a run (``hil.analysis.analyze.analyze``) or a simulation (``hil.sim``)."""

    schema_version: int
    kind: str  # "run"; absent for a simulation
    final_position_error: float | None
    final_heading_error: float | None
    rms_position_error: float | None
    initial_position_error: float | None
    max_abs_v: float | None
    max_abs_omega: float | None
    max_abs_tau1: float | None
    max_abs_tau2: float | None
    violations: dict[str, int]
    # plant steps whose state or applied torque was not finite, and the end time of the first
    # (None: none); never "limits held" (hil.verdict)
    nonfinite_steps: int
    nonfinite_first_t_s: float | None
    law_fault: dict[str, Any]  # controller_service.laws.guard.LawFault.to_dict(); absent: none
    samples: int
    duration: float
    # a run
    lockstep: bool
    cmd_path: str
    trigger: str
    rate_hz: float
    timing: dict[str, Any]  # figure name -> percentiles or count (docs/realtime.md)
    messages: dict[str, Any]  # stream -> sent, received, lost, duplicated, reordered
    certificate: Certificate | None
    host: dict[str, Any] | None
    logs_complete: dict[str, bool]
    rejections: dict[str, Any]
    watchdog: dict[str, int]
    can: dict[str, Any]
    faults: dict[str, Any]
    scheduling: dict[str, Any]
    interrupted: bool
    recovered: bool
    error: str | None
    duration_run_s: float | None
    duration_planned_s: float
    controller_exit: ControllerExit  # absent: the controller outlived the plant
    verdict: dict[str, Any]  # hil.verdict.Verdict.as_dict()
    # a simulation
    limits: dict[str, float]
    law: str
    ts: float
    plant_step: float
    seeds: dict[str, int]

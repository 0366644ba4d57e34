"""The typed records a run folder holds (docs/run-folder.md): summary.json and its certificate;
and what the bench hands the analysis with the raw folder it wrote (:class:`Recorded`).

JSON objects on disk and dicts in memory (scripts read them as such); these TypedDicts say which
keys exist and what each holds, so that a reader and a type checker agree with the writer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

from hil.limits import Constraint

if TYPE_CHECKING:
    from controller_service.laws.base import DesignContext
    from hil.scenario import Scenario
    from protocol.settings import RunSettings


class StallEvidence(TypedDict, total=False):
    """What the decision table of hil.analysis.measure.stalls found in a stall's window (each
    figure only where it was seen; docs/reports.md, "Stalls")."""

    host: HostLoad
    recorder_silent_s: float
    controller_stalled_s: float
    plant_stalled_s: float
    both_stalled_s: float
    bench_stalled_s: float
    controller_starved: bool
    frames_dropped_by_bench: int
    row: int  # the decision table's row that matched
    controller_lateness_s: float
    controller_silent_s: float
    plant_lateness_s: float
    plant_silent_s: float
    states_lost: int
    states_dropped_by_faults: int
    commands_lost: int
    commands_dropped_by_faults: int
    frames_not_on_bus: int
    commands_dropped_by_bench: int
    transport_worst_s: float
    landings_delayed_by_faults: int


class Stall(TypedDict, total=False):
    t_s: float
    age_s: float
    cause: str
    owner: str
    evidence: StallEvidence


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


class Percentiles(TypedDict, total=False):
    """One timing figure's distribution, in microseconds (hil.analysis.measure.stats)."""

    count: int
    p50_us: float | None
    p90_us: float | None
    p99_us: float | None
    p999_us: float | None
    max_us: float | None
    mean_us: float | None
    not_relatable: int  # CAN frames the logs could match to more than one send
    negative: int  # durations below zero (clocks not related)
    # a window's (hil.analysis.measure.windows): where its largest command age ended, and of
    # how many segments
    max_at_ns: int | None
    segments: int


class TickPhase(TypedDict, total=False):
    """Where the periodic ticks fell after the sample (controller_service.tick_phase); "auto"
    adds what the phase was learnt from."""

    rule: str  # "half" or "auto" (protocol.settings.TICK_PHASES)
    phase_us: float
    arrival_p99_us: float
    path_p99_us: float
    window_open: bool
    clocks_related: bool
    from_tick: int


# summary.json's ``timing``: each figure of docs/realtime.md by name (the per-path figures once
# per command path, protocol.settings.CMD_PATHS); a run measures the ones its logs allow.
class Timing(TypedDict, total=False):
    units: str
    window_s: float
    wakeup_lateness: Percentiles
    deadline_misses: int
    late_ticks: int
    skipped_slots: int
    ticks: int
    slots: int
    deadline_miss_rate: float
    period_jitter: Percentiles
    tick_phase: TickPhase
    plant_wakeup_lateness: Percentiles
    plant_deadline_misses: int
    plant_late_samples: int
    plant_skipped_slots: int
    plant_slots: int
    plant_deadline_miss_rate: float
    plant_sample_to_send: Percentiles
    compute: Percentiles
    hop_state: Percentiles
    wait_for_tick: Percentiles
    hop_cmd_zenoh: Percentiles
    hop_cmd_can: Percentiles
    loop_transport_compute: Percentiles
    state_send_to_cmd_recv: Percentiles
    sample_to_apply_zenoh: Percentiles
    sample_to_apply_can: Percentiles
    command_age_zenoh: Percentiles
    command_age_can: Percentiles
    startup_hold_s: float
    samples_without_command: int
    samples_judged: int
    samples_without_command_rate: float
    # samples without a command the plant's own late wake-up left so (the bench's)
    samples_without_command_plant_late: int
    late_commands: int
    late_commands_rate: float
    sample_gap: Percentiles


class StreamCounts(TypedDict, total=False):
    """One stream's messages (summary.json's ``messages``: "state", "torque_zenoh",
    "torque_can"): sent, received, lost, duplicated, reordered, and what was injected; the CAN
    stream adds its frames' counts."""

    sent: int
    received: int
    lost: int
    duplicated: int
    reordered: int
    injected_drops: int
    injected_duplicates: int
    injected_reorders: int
    lost_not_injected: int
    lost_not_injected_t_s: list[float]
    sent_after_window: int
    # sent after the newest that arrived, never received: in flight when the receiver stopped
    in_flight_at_stop: int
    ambiguous: int


Messages = dict[str, StreamCounts]  # stream name -> its counts


class HostLoad(TypedDict, total=False):
    """The host over the run's window (hil.bench.host_load's samples, hil.analysis.measure.host)."""

    from_s: str
    busy_pct: float
    steal_pct: float
    runnable_max: int
    cpus: int
    plant_cpu_pct: float
    controller_cpu_pct: float
    recorder_cpu_pct: float
    plant_wait_s: float
    controller_wait_s: float


class VerdictRecord(TypedDict, total=False):
    """hil.verdict.Verdict.as_dict(): summary.json's and report.json's ``verdict``."""

    outcome: str
    fail_reasons: list[str]
    inconclusive_reasons: list[str]
    advice: list[str]
    notes: list[str]
    limits: str
    limits_broken: list[str]
    certificate: str
    timing: Timing
    thresholds: dict[str, float]
    ok: bool
    reasons: list[str]
    deadline_misses: int | None
    samples_without_command: int | None
    lost_messages: int | None


class Scheduling(TypedDict, total=False):
    """How a service ran (runtime.realtime): the policy asked for and the one obtained."""

    requested: str
    policy: str
    priority: int
    affinity: list[int]
    mlockall: bool
    gc_frozen: bool
    helper_threads: int
    idle: str
    errors: dict[str, str]


class LawFaultRecord(TypedDict, total=False):
    """law_fault.json and summary.json's ``law_fault``
    (controller_service.laws.guard.LawFault.to_dict)."""

    law: str
    where: str  # its import path, module:Class
    kind: str  # "exception", "non_finite", "wrong_type", or "unreadable" (a bad file)
    t_s: float | None
    state: dict[str, float | None]
    reference: dict[str, float | None]
    robot: int | None
    detail: str
    traceback: str


class Recovered(TypedDict, total=False):
    """recovered.json: what hil recover repaired (hil.bench.repair.repair)."""

    folder: str
    repaired: list[str]  # the files that were missing or incomplete
    restore_error: str
    recording: dict[str, int]  # the recording rewritten: its counts
    analysed: bool


class ControllerExit(TypedDict, total=False):
    """The controller process ended before the plant did (``hil run`` then stops the run at
    once): its exit code, or the signal that killed it, and when, in seconds from the run's
    epoch (as ``hil run`` saw it, within its 50 ms poll)."""

    code: int | None  # None: killed by a signal
    signal: str | None  # e.g. "SIGKILL"
    t_s: float | None
    law_fault: bool  # it exited because its law failed (law_fault.json)
    output: str  # its console output, relative to the run folder (controller.log)


class RateLimit(TypedDict, total=False):
    """The loopback's token bucket of an [impair] rate limit (tc's counters)."""

    rate_bps: float
    packets: int | None
    dropped_packets: int | None
    overlimits: int | None
    burst_bytes: int | None
    latency: str
    mtu: int


class ImpairFacts(TypedDict, total=False):
    """summary.json's ``impair``: the [impair] table and the kernel's counts
    (hil.bench.impair.finish)."""

    config: dict[str, float | str]  # [impair] as it ran
    namespace: str
    packets: str
    rules: str  # the nftables rules' file in the folder
    matched_packets: int | None
    dropped_packets: int | None
    rate_limit: RateLimit | None
    error: str


class RunExtra(TypedDict, total=False):
    """What the bench adds to summary.json about the run itself, in this key order
    (:func:`hil.bench.lifecycle.run_extra`; a fleet's group, ``hil recover`` and [impair] add
    theirs): facts of the processes and the recorder, never a figure of the hop logs."""

    interrupted: bool
    until_stopped: bool  # --until-stopped: ended by Ctrl-C as planned
    error: str | None  # the system's: the run could not start (no outside device came): FAIL
    bench_error: str | None  # the bench's: it did not start the run (INCONCLUSIVE)
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
    impair: ImpairFacts


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
    law_fault: LawFaultRecord  # absent: none
    samples: int
    duration: float
    # a run
    lockstep: bool
    cmd_path: str
    trigger: str
    rate_hz: float
    timing: Timing  # figure name -> percentiles or count (docs/realtime.md)
    messages: Messages  # stream -> sent, received, lost, duplicated, reordered
    certificate: Certificate | None
    # the device at the bus, from plant.hoplog alone (hil.analysis.measure.device's
    # DeviceFigures, as_dict/from_dict); absent: no plant sample
    device: dict[str, Any]
    host: HostLoad | None
    logs_complete: dict[str, bool]
    logs_unreadable: dict[str, str]  # service -> why its log could not be read; absent: none
    rejections: dict[str, Any]
    watchdog: dict[str, int]
    can: dict[str, Any]
    faults: dict[str, Any]
    # each drive's disarm and the device's reaction (hil.analysis.measure.reactions)
    drive_reactions: list[dict[str, Any]]
    scheduling: dict[str, Scheduling | None]  # service -> how it ran
    interrupted: bool
    until_stopped: bool
    recovered: bool
    error: str | None
    duration_run_s: float | None
    duration_planned_s: float
    controller_exit: ControllerExit  # absent: the controller outlived the plant
    verdict: VerdictRecord
    run_dir: str  # hil run's own copy, not in summary.json
    # a simulation
    limits: dict[str, float]
    law: str
    ts: float
    plant_step: float
    seeds: dict[str, int]


class ScenarioBlock(TypedDict, total=False):
    """report.json's ``scenario``: what of the resolved scenario the report states."""

    law: str
    ts: float
    delay: float
    jitter: float
    jitter_kind: str
    limits: dict[str, float]  # [limits]: phi1, phi2, varpi1, varpi2
    eps1: float
    eps2: float


class Metrics(TypedDict, total=False):
    """report.json's ``metrics``: the sampling effects of the trace
    (hil.analysis.trace_metrics.sampling_effects) with summary.json's peaks folded in."""

    duration: float
    samples: int
    tracking: dict[str, float | None]
    bands: dict[str, dict[str, float] | None]
    switching_rate: dict[str, float]
    saturation_share: dict[str, float]
    constraints: dict[str, Constraint]  # signal (hil.limits.LIMITS) -> its constraint
    deviation_from_ideal: dict[str, float] | None
    deviation_from_ideal_note: str
    bands_source: str


class DrivesBlock(TypedDict, total=False):
    """report.json's ``drives``: the motor torques the wheel mapping makes of tau1, tau2, the
    drives' states and the rejection counts (hil.analysis.report.build.drives_block)."""

    geometry: dict[str, float] | None  # protocol.can.wheel_mapping.RobotGeometry
    note: str
    motor_torque_limit_nm: float
    max_abs_q_right_nm: float
    max_abs_q_left_nm: float
    can: dict[str, Any] | None  # summary.json's ``can``, as the services wrote it
    rejections: dict[str, Any] | None  # summary.json's ``rejections``
    rejection_counts: dict[str, int] | None


class ReportTiming(TypedDict, total=False):
    """report.json's ``timing``: summary.json's figures and where they came from."""

    summary: Timing | None
    messages: Messages | None
    source: str | None
    applied_path: str | None
    series: str | None
    faults: dict[str, Any] | None
    scheduling: dict[str, Scheduling | None] | None
    impair: ImpairFacts | None


class LimitShare(TypedDict):
    max: float
    limit: float
    percent_of_limit: float
    violations: int | None  # plant steps beyond it


class LimitsAnswer(TypedDict, total=False):
    held: bool
    v: LimitShare
    omega: LimitShare
    tau1: LimitShare
    tau2: LimitShare


class AgeAnswer(TypedDict, total=False):
    path: str | None
    d_max_s: float | None
    d_star_s: float | None
    margin_s: float | None
    held: bool | None
    source: str


class StallsAnswer(TypedDict, total=False):
    threshold_s: float | None
    listed: int
    count: int
    top: list[Stall]
    stalled_time_s: float | None


class SamplesAnswer(TypedDict):
    count: int | None
    judged: int | None
    rate: float | None


class Headline(TypedDict, total=False):
    """report.json's ``headline``: the four answers and the verdict, as data and as the report's
    first lines (hil.analysis.report.content.headline)."""

    verdict: str
    limits: LimitsAnswer
    command_age: AgeAnswer
    stalls: StallsAnswer
    samples_without_command: SamplesAnswer
    lines: list[dict[str, str]]  # {"key": answer, "text": its line}


class Topology(TypedDict, total=False):
    """topology.json of a run across lab hosts (hil.bench.lab.placement.write_topology), and
    report.json's ``topology`` (with the injected offsets)."""

    lab: str
    processes: dict[str, str]  # process -> its host
    hosts: dict[str, dict[str, Any]]  # host -> address, offset_s, router, impair
    session_endpoint: str
    router_hops: dict[str, list[str]]  # stream -> the routers it crosses
    clock_source: str
    clock: dict[str, Any]  # hil.folder.clocks.ClockTrack.facts(), the cross-host figures
    injected_offsets_s: list[float | None]
    injected_difference_s: float | None


class ReportData(TypedDict, total=False):
    """report.json (docs/reports.md): what hil report and hil run's report write."""

    schema_version: int
    folder: str
    kind: str  # "run" or "simulation"
    scenario: ScenarioBlock
    sections: list[str]
    metrics: Metrics
    certificate: Certificate
    drives: DrivesBlock
    timing: ReportTiming
    verdict: VerdictRecord
    margin: dict[str, Any] | None  # hil.analysis.margin.record.MarginRecord.to_dict()
    summary: dict[str, Any]  # summary.json's plain values
    headline: Headline
    topology: Topology
    figures: list[dict[str, str]]

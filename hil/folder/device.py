"""The device's figures as records (summary.json's ``device`` object): what
:mod:`hil.analysis.measure.device` measures at the bench's edge and what the verdict
(:mod:`hil.verdict`) and the report read; docs/realtime.md, "Figures of a device at the bus",
defines each."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

from hil.folder.records import Percentiles


@dataclass(frozen=True)
class DeviceLimits:
    """The limits a device's torques are judged against: varpi1, varpi2 of (2) (Zenoh) and the
    largest motor torque (2) asks of one wheel (CAN: protocol.can.wheel_mapping.
    motor_torque_limit), None where unknown."""

    varpi1: float
    varpi2: float
    motor_nm: float | None = None


@dataclass(frozen=True)
class Gap:
    """One gap of a command stream (module docstring): times in s, ``start_s`` since the epoch."""

    start_s: float
    interval_s: float
    length_s: float
    owner: str  # "device" or "bench"


@dataclass(frozen=True)
class CommandStream:
    """One stream of the device's commands: ``zenoh``, or ``node N`` (one wheel on CAN)."""

    name: str
    node: int | None
    commands: int
    period: Percentiles  # the inter-arrivals
    period_mean_s: float | None
    jitter: Percentiles  # |inter-arrival - P|
    gap_count: int
    gap_longest_s: float | None  # the longest gap's length (interval - P)
    gaps: list[Gap] = field(default_factory=list)  # the longest LISTED_GAPS, by start time
    first_command_s: float | None = None  # since the epoch

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> CommandStream:
        fields = dict(d)
        fields["gaps"] = [Gap(**g) for g in d.get("gaps") or []]
        return cls(**fields)


@dataclass(frozen=True)
class Beyond:
    """Commands of the device beyond one limit: ``signal`` (tau1, tau2, or "q node N": a motor
    torque on CAN), the limit, how many, and the worst value asked."""

    signal: str
    limit: float
    count: int
    worst: float | None  # the largest |value| asked, signed (None: every one was non-finite)
    non_finite: int = 0  # of the count: NaN or infinite torques

    def worst_words(self) -> str:
        """The worst value asked, in words."""
        nf = f"{self.non_finite} non-finite" if self.non_finite else ""
        if self.worst is None:
            return nf
        return f"{self.worst:.4g}" + (f" (and {nf})" if nf else "")


@dataclass(frozen=True)
class BusActivity:
    """What the device did on the bus, as the drives and the plant counted it (never fatal)."""

    state_requests: int | None
    clear_errors: int | None
    watchdog_trips: int | None
    armed: int | None
    malformed: int
    unknown: int
    refused: int
    command_timeouts: int  # the plant's: no command for [timing] command_timeout
    rejections: dict[str, int] = field(default_factory=dict)  # every reason counted

    @property
    def any_trouble(self) -> bool:
        return bool(self.malformed or self.unknown or self.refused or self.watchdog_trips)


@dataclass(frozen=True)
class DeviceFigures:
    """The device's figures (module docstring); summary.json's ``device`` object."""

    path: str  # "zenoh" or "can": the applied path
    outside: bool  # no controller.hoplog: the device is not the bench's controller
    nominal_period_s: float
    streams: list[CommandStream]
    response: Percentiles
    responses_unanswered: int  # States (encoder frames) no command answered
    age: Percentiles  # at landing: exact on Zenoh, a lower bound on CAN
    age_is_bound: bool
    d_max_s: float | None  # the largest age at landing (a lower bound on CAN)
    unnamed: int  # Zenoh commands naming no State the plant sent (counted rejections)
    beyond_limits: list[Beyond]
    bus: BusActivity
    samples_judged: int
    samples_in_gaps: int  # inside the device's own gaps
    samples_in_bench_gaps: int  # inside gaps the bench's stalls made
    # what P is: "control period" (the bench's own controller), "device median" (an outside
    # device: the median of its own command intervals, its rate not known to the bench)
    nominal_period_from: str = "control period"

    @property
    def gaps(self) -> list[Gap]:
        return sorted((g for s in self.streams for g in s.gaps), key=lambda g: g.start_s)

    @property
    def gap_count(self) -> int:
        return sum(s.gap_count for s in self.streams)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> DeviceFigures:
        f = dict(d)
        f["streams"] = [CommandStream.from_dict(s) for s in d.get("streams") or []]
        f["beyond_limits"] = [Beyond(**b) for b in d.get("beyond_limits") or []]
        f["bus"] = BusActivity(**(d.get("bus") or {}))
        return cls(**f)

"""Stalls: the stretches where the applied path's command age stayed above a threshold, each with
its cause and whose it is.

An **excursion** is a maximal stretch of plant time over which the command age (hil.measure.age)
stays above the threshold; it can span several landings (a first command that lands still too
old continues it). Every excursion is counted (``stall_count``) and its time above the threshold
summed (``stalled_time_s``); the worst ones are listed with a cause found by joining the logs
over [the sample in force at its start, the landing that ends it]:

| cause | evidence | owner |
|---|---|---|
| ``controller_late`` | a controller tick there woke a period or more late, or none woke | system |
| ``state_lost`` | plant samples there never reached the controller | system |
| ``command_lost`` | commands sent there never arrived | system |
| ``transport_late`` | a State or command there took a period or more on the wire (its | system |
|  | receiver on time: a message held up by a stalled receiver is the receiver's stall) | |
| ``command_delayed`` | landings delayed by a ``[faults]`` burst | system |
| ``plant_late`` | a plant sample there woke a period or more late | bench |
| ``host_stalled`` | the controller AND the plant were both a period or more late | bench |
| ``host_overloaded`` | the controller late while runnable, waiting for a CPU (run-queue | bench |
|  | wait >= half its lateness), the host's CPUs >= 90 % busy, half a CPU of it with | |
|  | processes not of this run (``host.hoplog``) | |
| ``startup`` | the stretch before the first landing (its owner from the same evidence) | either |
| ``unknown`` | none of these | unknown |

The system under test is the controller, its host's scheduling and the transport; the bench is the
plant emulator standing in for a robot that never stalls, the recorder and the bench's host.
``d_system_s`` is the largest age outside the bench's stalls: what the user's system alone did.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from hil.measure.age import AgeSegments
from hil.measure.host import PROCESSES


@dataclass(frozen=True)
class Stamped:
    """Rows of one kind sorted by a time stamp, with what a stall's cause needs of them."""

    stamps: np.ndarray
    late: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    arrived: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    injected: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    hop: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    off_bus: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # CAN: never sent

    @classmethod
    def by_time(cls, stamps: np.ndarray, **columns: np.ndarray) -> Stamped:
        """The rows (``stamps`` and the ``columns`` beside them) sorted by ``stamps``."""
        order = np.argsort(stamps, kind="stable")
        return cls(stamps[order], **{k: v[order] for k, v in columns.items()})


class _Run(Protocol):
    """What a stall's cause joins: the run's logs sorted by time once (hil.measure.figures)."""

    epoch: int
    w0: int
    period: int
    sensor_period: int
    trigger: str
    lockstep: bool
    samples: dict[str, np.ndarray]
    wake_sorted: Stamped
    state_received: np.ndarray
    state_injected_drop: np.ndarray
    commands_sorted: Stamped
    state_hops_sorted: Stamped
    burst_sorted: Stamped

    def host_over(self, lo: int, hi: int) -> dict[str, Any] | None: ...


STALL_LIMIT = 20  # stalls listed, worst first
HOST_BUSY_PCT = 90.0  # host_overloaded: the CPUs this busy over the stall ...
HOST_OTHERS_PCT = 50.0  # ... with at least this much of one CPU going to other processes
CAUSE_LIMIT = 2000  # excursions whose cause is looked up (every one above D*, then the worst)
_SYSTEM = ("controller_late", "state_lost", "command_lost", "transport_late", "command_delayed")
_BENCH = ("plant_late", "host_stalled", "host_overloaded")
OWNER = {**dict.fromkeys(_SYSTEM, "system"), **dict.fromkeys(_BENCH, "bench"), "unknown": "unknown"}


@dataclass
class Excursions:
    """Maximal stretches of age above the threshold, as segment index ranges [first, last]."""

    first: np.ndarray
    last: np.ndarray
    peak: np.ndarray  # ns, the largest age of each
    enter: np.ndarray  # ns, when the age crossed the threshold
    above: np.ndarray  # ns, time spent above the threshold


def excursions(seg: AgeSegments, threshold_ns: int) -> Excursions:
    """The excursions of the saw-tooth age above ``threshold_ns``."""
    peaks = seg.peak
    over = peaks > threshold_ns
    z = np.zeros(0, np.int64)
    if not over.any():
        return Excursions(z, z, z, z, z)
    idx = np.nonzero(over)[0]
    # Segment j continues the excursion of j - 1 when the age never fell to the threshold
    # between them: at j's start (the new landing) the age is still above it.
    start_age = seg.start - seg.sample
    cont = np.zeros(idx.size, bool)
    cont[1:] = (idx[1:] == idx[:-1] + 1) & (start_age[idx[1:]] > threshold_ns)
    heads = np.nonzero(~cont)[0]
    first = idx[heads]
    last = idx[np.append(heads[1:], idx.size) - 1]
    enter_seg = np.maximum(seg.start, seg.sample + threshold_ns)
    above_seg = np.where(over, seg.end - enter_seg, 0)
    csum = np.concatenate([[0], np.cumsum(above_seg)])
    peak = np.maximum.reduceat(peaks[idx], heads)
    return Excursions(first, last, peak, enter_seg[first], csum[last + 1] - csum[first])


@dataclass
class StallReport:
    listed: list[dict[str, Any]] = field(default_factory=list)
    count: int = 0
    stalled_time_ns: int = 0
    by_owner: dict[str, dict[str, float]] = field(default_factory=dict)
    d_system_ns: int | None = None
    bench_windows: list[tuple[int, int]] = field(default_factory=list)  # [lo, hi] ns


def find_stalls(
    r: _Run, seg: AgeSegments, threshold_ns: int, d_star_ns: int | None = None
) -> StallReport:
    """Every excursion counted, the worst listed with cause and owner, and D outside the
    bench's stalls (module docstring)."""
    ex = excursions(seg, threshold_ns)
    rep = StallReport(count=int(ex.first.size), stalled_time_ns=int(ex.above.sum()))
    order = np.argsort(-ex.peak, kind="stable")
    must = int((ex.peak > d_star_ns).sum()) if d_star_ns is not None else 0
    looked = order[: max(STALL_LIMIT, min(must, CAUSE_LIMIT))]
    bench = np.zeros(len(seg), bool)  # segments inside the bench's stalls
    for e in looked.tolist():
        j0, j1 = int(ex.first[e]), int(ex.last[e])
        cause, evidence = cause_of(r, int(seg.sample[j0]), int(seg.end[j1]))
        owner = OWNER[cause]
        startup = j0 == 0 and int(seg.start[0]) == r.w0 and int(seg.sample[0]) == r.w0
        if startup:
            cause = "startup"  # the zero torque held from t = 0 to the first landing
        bench[j0 : j1 + 1] = owner == "bench"
        if owner == "bench":
            rep.bench_windows.append((int(seg.sample[j0]), int(seg.end[j1])))
        t = rep.by_owner.setdefault(owner, {"count": 0, "time_s": 0.0})
        t["count"] += 1
        t["time_s"] += int(ex.above[e]) / 1e9
        if len(rep.listed) < STALL_LIMIT:
            t_s = 0.0 if startup else (int(ex.enter[e]) - r.epoch) / 1e9
            age_s = int(ex.peak[e]) / 1e9
            rep.listed.append(
                dict(t_s=t_s, age_s=age_s, cause=cause, owner=owner, evidence=evidence)
            )
    rest = seg.peak[~bench]
    rep.d_system_ns = int(rest.max()) if rest.size else None
    return rep


def _between(sorted_stamps: np.ndarray, lo: int, hi: int) -> slice:
    a = int(np.searchsorted(sorted_stamps, lo, side="left"))
    b = int(np.searchsorted(sorted_stamps, hi, side="right"))
    return slice(a, b)


def _longest_quiet(stamps: np.ndarray, lo: int, hi: int) -> int:
    """The longest stretch of [lo, hi] without a stamp (stamps sorted)."""
    inside = stamps[_between(stamps, lo, hi)]
    return int(np.diff(np.concatenate([[lo], inside, [hi]])).max())


def cause_of(r: _Run, lo: int, hi: int) -> tuple[str, dict[str, Any]]:
    """The cause of a stall over [lo, hi] and its evidence: the largest score wins; a
    controller and a plant both late there is the host's stall."""
    scores: dict[str, float] = {}
    ev: dict[str, Any] = {}
    w, s = r.wake_sorted, r.samples
    if r.trigger == "periodic" and w.stamps.size:
        late = w.late[_between(w.stamps, lo, hi)]
        _late_or_silent("controller", late, _longest_quiet(w.stamps, lo, hi), r.period, scores, ev)
    if not r.lockstep and s["wake_ns"].size:
        sl = _between(s["sample_ns"], lo, hi)
        late = s["wake_ns"][sl] - s["sample_ns"][sl]
        quiet = _longest_quiet(s["sample_ns"], lo, hi)
        _late_or_silent("plant", late, quiet, r.sensor_period, scores, ev)
    _message_evidence(r, lo, hi, scores, ev)
    if "controller_late" in scores and "plant_late" in scores:
        scores["host_stalled"] = max(scores.pop("controller_late"), scores.pop("plant_late"))
    host = r.host_over(lo, hi)
    if host is not None:
        ev["host"] = host
    if not scores:
        return "unknown", ev
    cause = max(scores, key=lambda k: scores[k])
    if cause == "controller_late" and host is not None and _overloaded(host, scores[cause]):
        cause = "host_overloaded"  # late because the host's CPUs went to others
    return cause, ev


def _overloaded(host: dict[str, Any], late_ns: float) -> bool:
    """The host's CPUs were nearly all busy, at least half a CPU of it with processes that are
    not this run's (the bench's host load, not the system under test), AND the controller spent
    at least half its lateness runnable but waiting for a CPU (its run-queue wait,
    /proc/PID/schedstat): a controller that was stopped or blocked waits on no run queue, and
    its lateness is its own even on a busy host."""
    ours = sum(host.get(f"{p}_cpu_pct", 0.0) for p in PROCESSES)
    others = host["busy_pct"] * host["cpus"] - ours
    waited = host.get("controller_wait_s")
    starved = waited is not None and waited * 1e9 >= 0.5 * late_ns
    return host["busy_pct"] >= HOST_BUSY_PCT and others >= HOST_OTHERS_PCT and starved


def _late_or_silent(
    who: str, late: np.ndarray, quiet: int, period: int, scores: dict, ev: dict
) -> None:
    """``who`` late over a stall: the worst ``late`` of its wake-ups there, or no wake-up at all
    for ``quiet`` >= two periods (the controller down: killed, restarting; the plant sleeping
    through slots), the latest of lates."""
    if late.size:
        worst = int(late.max())
        ev[f"{who}_lateness_s"] = worst / 1e9
        if worst >= period:
            scores[f"{who}_late"] = worst
    if quiet >= 2 * period:
        ev[f"{who}_silent_s"] = quiet / 1e9
        scores[f"{who}_late"] = max(scores.get(f"{who}_late", 0), quiet)


def _message_evidence(r: _Run, lo: int, hi: int, scores: dict, ev: dict) -> None:
    s = r.samples
    sl = _between(s["sample_ns"], lo, hi)
    lost = ~r.state_received[sl]
    if lost.any():
        ev["states_lost"] = int(lost.sum())
        ev["states_dropped_by_faults"] = int(r.state_injected_drop[sl][lost].sum())
        scores["state_lost"] = int(lost.sum()) * r.sensor_period
    c = r.commands_sorted
    sl = _between(c.stamps, lo, hi)
    lost_c = ~c.arrived[sl]
    if lost_c.any():
        ev["commands_lost"] = int(lost_c.sum())
        ev["commands_dropped_by_faults"] = int(c.injected[sl][lost_c].sum())
        if c.off_bus.any():  # CAN: frames that never reached the bus (bus-off)
            ev["frames_not_on_bus"] = int(c.off_bus[sl][lost_c].sum())
        scores["command_lost"] = int(lost_c.sum()) * r.period
    # A message held up by a stalled receiver, or by a stalled sender (stamped, then stopped
    # before it left), is that end's stall, not the wire's: a hop either end's lateness covers
    # (within a period) is no evidence against the wire.
    ends = max(scores.get("plant_late", 0), scores.get("controller_late", 0))
    hs = r.state_hops_sorted
    hops = np.concatenate([c.hop[sl], hs.hop[_between(hs.stamps, lo, hi)]])
    hops = hops[hops > ends + r.period]  # never negative: -1 is a command that never arrived
    worst = int(hops.max()) if hops.size else 0
    if worst >= r.period:
        ev["transport_worst_s"] = worst / 1e9
        scores["transport_late"] = worst
    b = r.burst_sorted
    sl = _between(b.stamps, lo, hi)
    if sl.stop > sl.start:
        ev["landings_delayed_by_faults"] = sl.stop - sl.start
        scores["command_delayed"] = int(b.hop[sl].max())

"""Stalls: the stretches where the applied path's command age stayed above a threshold, each with
its cause and whose it is, decided by one ordered table.

An **excursion** is a maximal stretch of plant time over which the command age
(hil.analysis.measure.age)
stays above the threshold; it can span several landings (a first command that lands still too
old continues it). Every excursion is counted (``stall_count``) and its time above the threshold
summed (``stalled_time_s``); the worst ones are listed with a cause found by joining the logs
over the stall [the sample in force at its start, the landing that ends it].

**The evidence** over a stall whose peak age is A, with θ the stall threshold (so A - θ is what a
cause must account for: without that much of the stall the age would have stayed at or under θ):

- *the controller stalled*: the stretches in which it woke a period or more late (deadline to
  wake-up) or logged nothing at all for two periods or more (no stamp of any of its threads:
  stopped, killed, the host not running it); periodic trigger only (on_state and lockstep wait
  by design); an outside device, whose ticks and receipts the bench does not see: its commands
  silent at the plant for two periods or more outside the plant's own stalls (the device or its
  transport, both the system's), and none of its States is called lost;
- *the plant stalled*: the same of the plant's samples (due to wake-up, a sensor period or more)
  and of all its stamps (two sensor periods); not in lockstep;
- *starved*: over the stall (host samples bracketing it, hil.analysis.measure.host) the controller's
  threads waited runnable for a CPU for at least half of its stalled time, while the host's CPUs
  were at least 90 % busy and at least half a CPU of that went to processes not of this run; or the
  hypervisor stole at least half that much CPU time (steal);
- *the bench's stalls*: the plant's stalled stretches, the controller's when it was starved, and
  the stretches the commands the bench's own receiving socket dropped left without a landing (the
  virtual drives' SocketCAN or UDP receive queue: the kernel's drop count, ``SO_RXQ_OVFL``); a
  stretch in which the controller and the plant were stalled at once is the bench's host;
- *lost messages*: the stretch between the delivered States (by sample time) or commands (by send
  time) around the ones that never arrived and that no bench socket dropped: lost on the wire or
  dropped by a ``[faults]`` injection, both the system's;
- *on the wire*: each State's and command's hop less the time either end was stalled in it (a
  message held up by a stalled sender or receiver is that end's stall, not the wire's);
- *delayed*: landings a ``[faults]`` burst delayed, by how much.

**The table** (the first row that matches wins, so the same evidence always gets the same answer;
"accounts for it" means the stretch is at least A - θ, "there" at least the floor named). A bench
row that accounts for the stall comes first: a stall the bench alone made is never laid on the
system; then a cause of the system's that accounts for it alone, then one that is merely there
(the system's own stall, even if the bench's added to it), then the bench's partial stalls, and
``unknown``. The stretch before the first landing is named ``startup``, its owner from the table.

<!-- stall-table:begin -->
 1. ``host_stalled`` (bench): the controller and the plant stalled at the same time (>= a
    period), and the bench's stalls account for it (>= A - θ)
 2. ``host_overloaded`` (bench): the controller stalled while starved of CPU by the host (>= a
    period), and the bench's stalls account for it (>= A - θ)
 3. ``plant_late`` (bench): the plant stalled: a sample late or none taken (>= a sensor period),
    and the bench's stalls account for it (>= A - θ)
 4. ``bench_dropped`` (bench): the bench's own receiving socket dropped frames there (>= one
    frame), and the bench's stalls account for it (>= A - θ)
 5. ``controller_late`` (system): the controller stalled outside the bench's stalls: a tick late
    or none woke (>= A - θ)
 6. ``state_lost`` (system): States lost on the wire or dropped by [faults] (>= A - θ)
 7. ``command_lost`` (system): commands lost on the wire, by [faults] or never put on the bus
    (>= A - θ)
 8. ``transport_late`` (system): a State or command on the wire, its ends' stalls taken out of
    its hop (>= A - θ)
 9. ``command_delayed`` (system): landings delayed by a [faults] burst (>= A - θ)
10. ``controller_late`` (system): the controller stalled outside the bench's stalls: a tick late
    or none woke (>= a period)
11. ``state_lost`` (system): States lost on the wire or dropped by [faults] (>= a sensor period)
12. ``command_lost`` (system): commands lost on the wire, by [faults] or never put on the bus
    (>= a period)
13. ``transport_late`` (system): a State or command on the wire, its ends' stalls taken out of
    its hop (>= a period)
14. ``command_delayed`` (system): landings delayed by a [faults] burst (>= any delay)
15. ``host_stalled`` (bench): the controller and the plant stalled at the same time (>= a
    period)
16. ``host_overloaded`` (bench): the controller stalled while starved of CPU by the host (>= a
    period)
17. ``plant_late`` (bench): the plant stalled: a sample late or none taken (>= a sensor period)
18. ``bench_dropped`` (bench): the bench's own receiving socket dropped frames there (>= one
    frame)
19. ``unknown`` (unknown): none of the above
<!-- stall-table:end -->

The system under test is the controller, its host's scheduling and the transport; the bench is the
plant emulator standing in for a robot that never stalls, the recorder and the bench's host.
``d_system_s`` is the largest age outside the bench's stalls: what the user's system alone did.
Each listed stall's ``evidence`` holds the figures the table read and ``row``, the row that
matched. docs/reports.md holds the same table (tests/test_stall_table.py checks both against
:func:`table_markdown`).
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from hil.analysis.measure.age import AgeSegments
from hil.analysis.measure.host import PROCESSES
from hil.folder.records import HostLoad, Stall, StallEvidence

STALL_LIMIT = 20  # stalls listed, worst first
HOST_BUSY_PCT = 90.0  # starved: the CPUs this busy over the stall ...
HOST_OTHERS_PCT = 50.0  # ... with at least this much of one CPU going to other processes ...
STARVED_SHARE = 0.5  # ... and the controller waiting for a CPU this share of its stall
CAUSE_LIMIT = 2000  # excursions whose cause is looked up (every one above D*, then the worst)
TABLE_BEGIN, TABLE_END = "<!-- stall-table:begin -->", "<!-- stall-table:end -->"


# --- stretches of time ----------------------------------------------------------------------


@dataclass(frozen=True)
class Stretches:
    """Disjoint stretches of time [lo, hi] in ns, sorted."""

    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def none(cls) -> Stretches:
        z = np.zeros(0, np.int64)
        return cls(z, z)

    @classmethod
    def of(cls, lo: np.ndarray, hi: np.ndarray) -> Stretches:
        """The union of the stretches [lo_i, hi_i] (any order, overlapping or not)."""
        lo, hi = np.asarray(lo, np.int64), np.asarray(hi, np.int64)
        keep = hi > lo
        lo, hi = lo[keep], hi[keep]
        if lo.size == 0:
            return cls.none()
        order = np.argsort(lo, kind="stable")
        lo, hi = lo[order], hi[order]
        reach = np.maximum.accumulate(hi)
        head = np.ones(lo.size, bool)
        head[1:] = lo[1:] > reach[:-1]  # a new stretch starts past everything before it
        starts = np.nonzero(head)[0]
        ends = np.append(starts[1:], lo.size) - 1
        return cls(lo[starts], reach[ends])

    @classmethod
    def silences(cls, stamps: np.ndarray, at_least: int) -> Stretches:
        """The stretches of at least ``at_least`` ns between consecutive ``stamps`` (any order):
        when a process that logs every period logged nothing."""
        s = np.unique(np.asarray(stamps, np.int64))
        s = s[s > 0]
        if s.size < 2 or at_least <= 0:
            return cls.none()
        gap = np.diff(s) >= at_least
        return cls.of(s[:-1][gap], s[1:][gap])

    def clip(self, a: int, b: int) -> Stretches:
        i = int(np.searchsorted(self.hi, a, side="right"))
        j = int(np.searchsorted(self.lo, b, side="left"))
        return Stretches(np.maximum(self.lo[i:j], a), np.minimum(self.hi[i:j], b))

    def total(self) -> int:
        return int((self.hi - self.lo).sum())

    def union(self, other: Stretches) -> Stretches:
        lo, hi = np.concatenate([self.lo, other.lo]), np.concatenate([self.hi, other.hi])
        return Stretches.of(lo, hi)

    def intersect(self, other: Stretches) -> Stretches:
        lo, hi = [], []
        for a, b in zip(other.lo.tolist(), other.hi.tolist(), strict=True):
            part = self.clip(a, b)
            lo.append(part.lo)
            hi.append(part.hi)
        if not lo:
            return Stretches.none()
        return Stretches.of(np.concatenate(lo), np.concatenate(hi))

    def covered(self, a: int, b: int) -> int:
        """How much of [a, b] these stretches cover."""
        return self.clip(a, b).total()

    def drained(self, recv: np.ndarray, hop: np.ndarray, period: int) -> Stretches:
        """These stalls of a receiver, each carried on until it had drained what queued up for
        it: to its first receipt after the stall whose hop is under ``period`` (``recv`` the
        receipts' times, sorted, ``hop`` their hops), or while none is, to its last receipt
        within the stall's own length after it (a receiver drains faster than it was fed). A
        message that waited in a stalled receiver's queue, behind the ones that came in while
        it was stopped, is that receiver's delay, not the wire's."""
        if self.lo.size == 0 or recv.size == 0:
            return self
        fresh = recv[hop < period]
        cap = self.hi + (self.hi - self.lo) + period
        if fresh.size:
            k = np.searchsorted(fresh, self.hi, side="left")
            first = np.where(k < fresh.size, fresh[np.minimum(k, fresh.size - 1)], cap + 1)
        else:
            first = cap + 1
        last = recv[np.maximum(np.searchsorted(recv, cap, side="right") - 1, 0)]
        end = np.where(first <= cap, first, np.where(last >= self.hi, last, self.hi))
        return Stretches.of(self.lo, np.maximum(self.hi, end))

    def minus(self, other: Stretches) -> Stretches:
        """These stretches less ``other``."""
        out_lo: list[int] = []
        out_hi: list[int] = []
        for a, b in zip(self.lo.tolist(), self.hi.tolist(), strict=True):
            cut = other.clip(a, b)
            edges = [a, *np.ravel(np.column_stack([cut.lo, cut.hi])).tolist(), b]
            for x, y in zip(edges[::2], edges[1::2], strict=True):
                if y > x:
                    out_lo.append(x)
                    out_hi.append(y)
        return Stretches(np.asarray(out_lo, np.int64), np.asarray(out_hi, np.int64))


# --- what the table reads -------------------------------------------------------------------


@dataclass(frozen=True)
class Evidence:
    """What the logs show over one stall, reduced to what the table reads (module docstring);
    every stretch in ns, clipped to the stall."""

    age_ns: int  # A, the stall's peak command age
    threshold_ns: int  # θ
    period_ns: int  # the controller's
    sensor_period_ns: int  # the plant's
    controller_ns: int = 0  # the controller's stalled time
    plant_ns: int = 0  # the plant's stalled time
    both_ns: int = 0  # both stalled at the same time
    starved: bool = False  # the controller starved of CPU by the host (module docstring)
    bench_dropped: int = 0  # frames the bench's own receiving sockets dropped there
    bench_ns: int = 0  # the bench's stalls: plant, starved controller, bench drops
    controller_own_ns: int = 0  # the controller's stalled time outside the bench's stalls
    states_lost_ns: int = 0  # the longest stretch of States lost (the system's)
    commands_lost_ns: int = 0  # the longest stretch of commands lost (the system's)
    wire_ns: int = 0  # the longest hop on the wire, its ends' stalls taken out
    burst_ns: int = 0  # the largest [faults] delay of a landing there

    @property
    def need_ns(self) -> int:
        """What a cause must account for: A - θ."""
        return self.age_ns - self.threshold_ns


@dataclass(frozen=True)
class Cause:
    """A cause: whose it is, what its evidence is, how to read its stretch and its floor (what
    makes it "there")."""

    name: str
    owner: str
    what: str
    stretch: Callable[[Evidence], int]
    floor: Callable[[Evidence], int]
    floor_words: str


_NEED = "(>= A - θ)"
_P = "a period"
_SP = "a sensor period"
CAUSES: dict[str, Cause] = {
    c.name: c
    for c in (
        Cause("host_stalled", "bench", "the controller and the plant stalled at the same time",
              lambda e: e.both_ns, lambda e: min(e.period_ns, e.sensor_period_ns), _P),
        Cause("host_overloaded", "bench", "the controller stalled while starved of CPU by the host",
              lambda e: e.controller_ns if e.starved else 0, lambda e: e.period_ns, _P),
        Cause("plant_late", "bench", "the plant stalled: a sample late or none taken",
              lambda e: e.plant_ns, lambda e: e.sensor_period_ns, _SP),
        Cause("bench_dropped", "bench", "the bench's own receiving socket dropped frames there",
              lambda e: e.bench_dropped, lambda e: 1, "one frame"),
        Cause("controller_late", "system",
              "the controller stalled outside the bench's stalls: a tick late or none woke",
              lambda e: e.controller_own_ns, lambda e: e.period_ns, _P),
        Cause("state_lost", "system", "States lost on the wire or dropped by [faults]",
              lambda e: e.states_lost_ns, lambda e: e.sensor_period_ns, _SP),
        Cause("command_lost", "system",
              "commands lost on the wire, by [faults] or never put on the bus",
              lambda e: e.commands_lost_ns, lambda e: e.period_ns, _P),
        Cause("transport_late", "system",
              "a State or command on the wire, its ends' stalls taken out of its hop",
              lambda e: e.wire_ns, lambda e: e.period_ns, _P),
        Cause("command_delayed", "system", "landings delayed by a [faults] burst",
              lambda e: e.burst_ns, lambda e: 1, "any delay"),
    )
}  # fmt: skip
BENCH = tuple(n for n, c in CAUSES.items() if c.owner == "bench")
SYSTEM = tuple(n for n, c in CAUSES.items() if c.owner == "system")
OWNER = {**{n: c.owner for n, c in CAUSES.items()}, "unknown": "unknown"}


@dataclass(frozen=True)
class Row:
    """One row of the table: ``cause`` matches when its evidence is there and, with
    ``accounts``, when the stretch that row reads (the bench's stalls for a bench cause, the
    cause's own for the system's) is at least A - θ."""

    cause: str
    accounts: bool

    def matches(self, e: Evidence) -> bool:
        if self.cause == "unknown":
            return True
        c = CAUSES[self.cause]
        there = c.stretch(e) >= max(1, c.floor(e))
        if not self.accounts:
            return there
        if c.owner == "bench":
            return there and e.bench_ns >= e.need_ns
        return there and c.stretch(e) >= e.need_ns

    def words(self) -> str:
        if self.cause == "unknown":
            return "none of the above"
        c = CAUSES[self.cause]
        if not self.accounts:
            return f"{c.what} (>= {c.floor_words})"
        if c.owner == "bench":
            return f"{c.what} (>= {c.floor_words}), and the bench's stalls account for it " + _NEED
        return f"{c.what} {_NEED}"


TABLE: tuple[Row, ...] = (
    *(Row(c, True) for c in BENCH),
    *(Row(c, True) for c in SYSTEM),
    *(Row(c, False) for c in SYSTEM),
    *(Row(c, False) for c in BENCH),
    Row("unknown", False),
)


def decide(e: Evidence) -> tuple[str, str, int]:
    """(cause, owner, row number from 1) of the first row of :data:`TABLE` that matches."""
    for i, row in enumerate(TABLE, 1):
        if row.matches(e):
            return row.cause, OWNER[row.cause], i
    raise AssertionError("the last row matches everything")  # pragma: no cover


def table_text(width: int = 96) -> str:
    """The table as this module's docstring holds it: one numbered entry a row, wrapped."""
    out = []
    for i, row in enumerate(TABLE, 1):
        text = f"{i:>2}. ``{row.cause}`` ({OWNER[row.cause]}): {row.words()}"
        out.append(textwrap.fill(text, width, subsequent_indent="    ", break_on_hyphens=False))
    return "\n".join(out)


def table_markdown() -> str:
    """The table as docs/reports.md and this module's docstring hold it."""
    lines = [
        "| # | cause | owner | matches when (over the stall; A its peak age, θ the threshold) |",
        "|---|---|---|---|",
    ]
    for i, row in enumerate(TABLE, 1):
        lines.append(f"| {i} | `{row.cause}` | {OWNER[row.cause]} | {row.words()} |")
    return "\n".join(lines)


# --- the run's logs, joined --------------------------------------------------------------------


@dataclass(frozen=True)
class Stamped:
    """Rows of one kind sorted by a time stamp, with what a stall's cause needs of them."""

    stamps: np.ndarray
    late: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    arrived: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    injected: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    hop: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    off_bus: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # CAN: never sent
    start: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # hop's start
    by_bench: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))  # a bench drop

    @classmethod
    def by_time(cls, stamps: np.ndarray, **columns: np.ndarray) -> Stamped:
        """The rows (``stamps`` and the ``columns`` beside them) sorted by ``stamps``."""
        order = np.argsort(stamps, kind="stable")
        return cls(stamps[order], **{k: v[order] for k, v in columns.items()})

    @property
    def hop_start(self) -> np.ndarray:
        return self.start if self.start.size == self.stamps.size else self.stamps


class _Run(Protocol):
    """What a stall's cause joins: the run's logs sorted by time once
    (hil.analysis.measure.figures)."""

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
    controller_stalls: Stretches
    plant_stalls: Stretches
    bench_drops: Stretches  # where the bench's own sockets dropped frames
    bench_drop_stamps: Stamped  # per drop seen: when, and how many (``hop``)
    host_gaps: Stretches  # where the recorder's host sampler logged nothing

    def host_over(self, lo: int, hi: int) -> HostLoad | None: ...


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
    listed: list[Stall] = field(default_factory=list)
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
        lo, hi = int(seg.sample[j0]), int(seg.end[j1])
        cause, owner, evidence = cause_of(r, lo, hi, int(ex.peak[e]), threshold_ns)
        startup = j0 == 0 and int(seg.start[0]) == r.w0 and int(seg.sample[0]) == r.w0
        if startup:
            cause = "startup"  # the zero torque held from t = 0 to the first landing
        bench[j0 : j1 + 1] = owner == "bench"
        if owner == "bench":
            rep.bench_windows.append((lo, hi))
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


def host_windows(r: _Run) -> list[tuple[int, int]]:
    """The bench's host stalls, however short: each stretch the controller stalled in while the
    plant stalled too for a period or more (the host ran neither: ``host_stalled``'s evidence)
    or while it was starved (:func:`starved`: ``host_overloaded``'s), with the plant's stalls it
    overlaps. One too short to raise the command age past the stall threshold makes no stall of
    the table (at 100 Hz, D* = 498 ms: a 30 ms stop of the whole machine), yet the slots it
    missed and the samples it left without a command are the bench's, as a longer one's are
    (hil.analysis.measure.figures._bench_shares): the same stop is never the system's for
    being short."""
    C, P = r.controller_stalls, r.plant_stalls
    lo: list[np.ndarray] = []
    hi: list[np.ndarray] = []
    for a, b in zip(C.lo.tolist(), C.hi.tolist(), strict=True):
        if P.covered(a, b) < r.period and not starved(r.host_over(a, b), b - a):
            continue
        i = int(np.searchsorted(P.hi, a, side="left"))
        j = int(np.searchsorted(P.lo, b, side="right"))
        lo += [np.array([a], np.int64), P.lo[i:j]]
        hi += [np.array([b], np.int64), P.hi[i:j]]
    if not lo:
        return []
    host = Stretches.of(np.concatenate(lo), np.concatenate(hi))
    return list(zip(host.lo.tolist(), host.hi.tolist(), strict=True))


def _between(sorted_stamps: np.ndarray, lo: int, hi: int) -> slice:
    a = int(np.searchsorted(sorted_stamps, lo, side="left"))
    b = int(np.searchsorted(sorted_stamps, hi, side="right"))
    return slice(a, b)


def starved(host: HostLoad | None, stalled_ns: int) -> bool:
    """The controller starved of CPU by the host over a stall in which it was stalled for
    ``stalled_ns`` (module docstring): runnable but waiting for a CPU for at least half of it
    while the host's CPUs were nearly all busy, at least half a CPU with processes that are not
    this run's; or the hypervisor stole at least half of it. A controller that was stopped or
    blocked waits on no run queue: its stall is its own even on a busy host."""
    if host is None or stalled_ns <= 0:
        return False
    need = STARVED_SHARE * stalled_ns / 1e9
    stolen = host.get("steal_pct", 0.0) / 100.0 * host["cpus"] * host["from_s"]
    if stolen >= need:
        return True
    ours = sum(host.get(f"{p}_cpu_pct", 0.0) for p in PROCESSES)
    others = host["busy_pct"] * host["cpus"] - ours
    waited = host.get("controller_wait_s")
    return (
        waited is not None
        and waited >= need
        and host["busy_pct"] >= HOST_BUSY_PCT
        and others >= HOST_OTHERS_PCT
    )


def evidence_of(
    r: _Run, lo: int, hi: int, age_ns: int, threshold_ns: int
) -> tuple[Evidence, StallEvidence]:
    """The evidence over the stall [lo, hi] (module docstring), and the figures behind it as
    the stall's ``evidence`` lists them (seconds, counts)."""
    ev: StallEvidence = {}
    C = r.controller_stalls.clip(lo, hi)
    P = r.plant_stalls.clip(lo, hi)
    both = C.intersect(P).total()
    host = r.host_over(lo, hi)
    if host is not None:
        ev["host"] = host
    gap = r.host_gaps.covered(lo, hi)
    if gap:
        ev["recorder_silent_s"] = gap / 1e9  # the host figures span the recorder's silence
    is_starved = starved(host, C.total())
    dropped, drops = _bench_drops(r, lo, hi)
    B = P.union(drops)
    if is_starved:
        B = B.union(C)
    own = C.minus(B)
    states_lost_ns, commands_lost_ns = _lost(r, lo, hi, ev)
    wire = _wire(r, lo, hi, ev)
    burst = _burst(r, lo, hi, ev)
    _lateness(r, lo, hi, ev)
    e = Evidence(
        age_ns=age_ns,
        threshold_ns=threshold_ns,
        period_ns=r.period,
        sensor_period_ns=r.sensor_period,
        controller_ns=C.total(),
        plant_ns=P.total(),
        both_ns=both,
        starved=is_starved,
        bench_dropped=dropped,
        bench_ns=B.total(),
        controller_own_ns=own.total(),
        states_lost_ns=states_lost_ns,
        commands_lost_ns=commands_lost_ns,
        wire_ns=wire,
        burst_ns=burst,
    )
    for key, value in (("controller", e.controller_ns), ("plant", e.plant_ns),
                       ("both", e.both_ns), ("bench", e.bench_ns)):  # fmt: skip
        if value:
            ev[f"{key}_stalled_s"] = value / 1e9  # type: ignore[literal-required]
    if is_starved:
        ev["controller_starved"] = True
    if dropped:
        ev["frames_dropped_by_bench"] = dropped
    return e, ev


def cause_of(
    r: _Run, lo: int, hi: int, age_ns: int, threshold_ns: int
) -> tuple[str, str, StallEvidence]:
    """(cause, owner, evidence) of the stall over [lo, hi] whose peak age is ``age_ns``: the
    first row of the table that matches (module docstring)."""
    e, ev = evidence_of(r, lo, hi, age_ns, threshold_ns)
    cause, owner, row = decide(e)
    ev["row"] = row
    return cause, owner, ev


def _lateness(r: _Run, lo: int, hi: int, ev: StallEvidence) -> None:
    """The worst wake-up lateness of either service there, and its longest silence (as the
    evidence lists them)."""
    w, s = r.wake_sorted, r.samples
    if r.trigger == "periodic" and w.stamps.size:
        late = w.late[_between(w.stamps, lo, hi)]
        if late.size:
            ev["controller_lateness_s"] = int(late.max()) / 1e9
        quiet = r.controller_stalls.clip(lo, hi)
        if quiet.lo.size:
            ev["controller_silent_s"] = int((quiet.hi - quiet.lo).max()) / 1e9
    if not r.lockstep and s["wake_ns"].size:
        sl = _between(s["sample_ns"], lo, hi)
        late = s["wake_ns"][sl] - s["sample_ns"][sl]
        if late.size:
            ev["plant_lateness_s"] = int(late.max()) / 1e9
        quiet = r.plant_stalls.clip(lo, hi)
        if quiet.lo.size:
            ev["plant_silent_s"] = int((quiet.hi - quiet.lo).max()) / 1e9


def _bench_drops(r: _Run, lo: int, hi: int) -> tuple[int, Stretches]:
    """Frames the bench's own receiving sockets dropped there, and the stretches they fell in."""
    d = r.bench_drop_stamps
    sl = _between(d.stamps, lo, hi)
    return int(d.hop[sl].sum()), r.bench_drops.clip(lo, hi)


def _gaps(stamps: np.ndarray, delivered: np.ndarray, lo: int, hi: int) -> int:
    """The longest stretch of [lo, hi] from a delivered message to the next delivered one with
    only undelivered ones between (``stamps`` sorted, ``delivered`` beside them)."""
    sl = _between(stamps, lo, hi)
    t, ok = stamps[sl], delivered[sl]
    if ok.all():
        return 0
    before = stamps[: sl.start][delivered[: sl.start]]
    after = stamps[sl.stop :][delivered[sl.stop :]]
    edges = np.concatenate(
        [before[-1:] if before.size else [lo], t[ok], after[:1] if after.size else [hi]]
    ).astype(np.int64)
    # the delivered one just after each lost (the stall's end where none is)
    i = np.clip(np.searchsorted(edges, t[~ok], side="right"), 1, edges.size - 1)
    span = np.minimum(edges[i], hi) - np.maximum(edges[i - 1], lo)
    return int(span.max())


def _lost(r: _Run, lo: int, hi: int, ev: StallEvidence) -> tuple[int, int]:
    """The longest stretches of lost States and commands (the system's), with their counts."""
    s = r.samples
    sl = _between(s["sample_ns"], lo, hi)
    got = r.state_received
    lost = ~got[sl]
    states_ns = 0
    if lost.any():
        ev["states_lost"] = int(lost.sum())
        ev["states_dropped_by_faults"] = int(r.state_injected_drop[sl][lost].sum())
        states_ns = _gaps(s["sample_ns"], got, lo, hi)
    c = r.commands_sorted
    sl = _between(c.stamps, lo, hi)
    lost_c = ~c.arrived[sl]
    commands_ns = 0
    if lost_c.any():
        ev["commands_lost"] = int(lost_c.sum())
        ev["commands_dropped_by_faults"] = int(c.injected[sl][lost_c].sum())
        if c.off_bus.any():  # CAN: frames that never reached the bus (bus-off)
            ev["frames_not_on_bus"] = int(c.off_bus[sl][lost_c].sum())
        bench = c.by_bench if c.by_bench.size == c.stamps.size else np.zeros(c.stamps.size, bool)
        if bench[sl][lost_c].any():
            ev["commands_dropped_by_bench"] = int(bench[sl][lost_c].sum())
        # A command the bench's own socket dropped is no loss of the system's.
        commands_ns = _gaps(c.stamps, c.arrived | bench, lo, hi)
    return states_ns, commands_ns


def _wire(r: _Run, lo: int, hi: int, ev: StallEvidence) -> int:
    """The longest time a State or command of the stall spent on the wire: its hop less the
    time either end was stalled in it (a message held up by a stalled sender, stamped and then
    stopped before it left, or by a stalled receiver is that end's stall, not the wire's)."""
    worst = 0
    for m in (r.commands_sorted, r.state_hops_sorted):
        sl = _between(m.stamps, lo, hi)
        hop, start = m.hop[sl], m.hop_start[sl]
        slow = np.nonzero(hop >= r.period)[0]  # -1: a command that never arrived
        for i in slow.tolist():
            a, b = int(start[i]), int(start[i] + hop[i])
            ends = r.controller_stalls.clip(a, b).union(r.plant_stalls.clip(a, b))
            worst = max(worst, b - a - ends.total())
    if worst:
        ev["transport_worst_s"] = worst / 1e9
    return worst


def _burst(r: _Run, lo: int, hi: int, ev: StallEvidence) -> int:
    b = r.burst_sorted
    sl = _between(b.stamps, lo, hi)
    if sl.stop <= sl.start:
        return 0
    ev["landings_delayed_by_faults"] = sl.stop - sl.start
    return int(b.hop[sl].max())

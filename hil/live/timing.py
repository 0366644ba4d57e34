"""The live view's timing figures (schema ``hil.LiveTiming`` in :mod:`hil.schemas`; docs/live.md).

Live estimates from the messages as the view receives them, for a person watching; the run's own
figures (docs/realtime.md) are measured afterwards from the hop logs. Command age at a State: its
sample time - the sample time of the newest TorqueCommand the view had seen when the State
arrived (before the first command, - the first State's); lateness: a command's compute start -
the previous command's - Ts (>= 0); states without command: States no command named
(``state_seq``) within 0.1 s of their arrival; the verdict so far: FAIL once a limit of (2)
broke, INCONCLUSIVE while D > D* or more than 1 % of the States went unanswered, else PASS.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from protocol.hoplog import NO_STAMP
from protocol.messages import State, Status, TorqueCommand

UNANSWERED_AFTER_NS = 100_000_000
UNANSWERED_RATIO = 0.01  # as hil.verdict's max_samples_without_command_ratio
LIMIT_REL_TOL = 1e-9


@dataclass(frozen=True)
class Bounds:
    """What the figures are judged against: D* (None: no certificate), Ts, limits (2)."""

    d_star_s: float | None
    ts_s: float
    phi1: float
    phi2: float


class LiveTiming:
    """Fed States, commands and Statuses in arrival order (by one thread); :meth:`snapshot`."""

    def __init__(self, bounds: Bounds) -> None:
        self.bounds = bounds
        self.states = self.commands = 0
        self.first_state_ns: int | None = None
        self.first_recv_ns: int | None = None
        self.in_force_sample_ns: int | None = None  # of the newest command seen
        self.age_now_ns: int | None = None
        self.age_max_ns: int | None = None
        self.last_compute_ns: int | None = None
        self.lateness_now_ns: int | None = None
        self.lateness_max_ns: int | None = None
        self.deadline_misses: int | None = None
        self.unanswered = 0
        self.pending: OrderedDict[int, int] = OrderedDict()  # state seq -> arrival
        self.max_v = self.max_w = 0.0

    def on_state(self, st: State, recv_ns: int) -> None:
        self.states += 1
        if self.first_state_ns is None:
            self.first_state_ns, self.first_recv_ns = st.sample_time_ns, recv_ns
        since = self.in_force_sample_ns
        age = st.sample_time_ns - (since if since is not None else self.first_state_ns)
        self.age_now_ns = age
        self.age_max_ns = age if self.age_max_ns is None else max(self.age_max_ns, age)
        self.max_v = max(self.max_v, abs(st.v))
        self.max_w = max(self.max_w, abs(st.omega))
        self.pending[st.seq] = recv_ns
        self._expire(recv_ns)

    def on_command(self, cmd: TorqueCommand, recv_ns: int) -> None:
        self.commands += 1
        # A watchdog zero or the final stop names no State (sample time NO_STAMP): taken as the
        # command in force, it made every State's age its sample time, the clock's own age.
        sample, newest = cmd.state_sample_time_ns, self.in_force_sample_ns
        if sample != NO_STAMP and (newest is None or sample > newest):
            self.in_force_sample_ns = sample
        if self.last_compute_ns is not None:
            gap = cmd.compute_start_ns - self.last_compute_ns
            late = max(0, gap - round(self.bounds.ts_s * 1e9))
            self.lateness_now_ns = late
            self.lateness_max_ns = max(self.lateness_max_ns or 0, late)
        self.last_compute_ns = cmd.compute_start_ns
        self.pending.pop(cmd.state_seq, None)

    def on_status(self, st: Status) -> None:
        if st.role == "controller" and "deadline_misses" in st.counters:
            self.deadline_misses = int(st.counters["deadline_misses"])

    def _expire(self, now_ns: int) -> None:
        while self.pending:
            seq, arrived = next(iter(self.pending.items()))
            if now_ns - arrived < UNANSWERED_AFTER_NS:
                break
            del self.pending[seq]
            self.unanswered += 1

    def verdict(self) -> tuple[str, str]:
        """(outcome, reasons) so far."""
        b = self.bounds
        if self.states == 0:
            return "WAITING", "no State yet"
        broken = []
        if self.max_v > b.phi1 * (1 + LIMIT_REL_TOL):
            broken.append(f"|v| {self.max_v:.3g} > phi1 {b.phi1:g}")
        if self.max_w > b.phi2 * (1 + LIMIT_REL_TOL):
            broken.append(f"|omega| {self.max_w:.3g} > phi2 {b.phi2:g}")
        if broken:
            return "FAIL", "limits of (2) broken: " + "; ".join(broken)
        doubts = []
        if b.d_star_s is not None and (self.age_max_ns or 0) > b.d_star_s * 1e9:
            doubts.append(
                f"command age {self.age_max_ns / 1e6:.2f} ms > D* {b.d_star_s * 1e3:.2f} ms"  # type: ignore[operator]
            )
        if self.unanswered > UNANSWERED_RATIO * self.states:
            doubts.append(f"{self.unanswered} of {self.states} States without a command")
        if doubts:
            return "INCONCLUSIVE", "; ".join(doubts)
        return "PASS", ""

    def snapshot(self, now_ns: int, backlog: int = 0) -> dict[str, Any]:
        """The figures now (the ``hil.LiveTiming`` message); ``backlog``: the view's queue.
        A figure not known yet (or D* without a certificate) is left out, not null."""
        self._expire(now_ns)
        d_star_ms = None if self.bounds.d_star_s is None else self.bounds.d_star_s * 1e3
        age_max_ms = _per(self.age_max_ns, 1e6)
        outcome, reasons = self.verdict()
        first = self.first_recv_ns if self.first_recv_ns is not None else now_ns
        figures = {
            "t_s": max(0.0, (now_ns - first) / 1e9),
            "states": self.states,
            "commands": self.commands,
            "command_age_now_ms": _per(self.age_now_ns, 1e6),
            "command_age_max_ms": age_max_ms,
            "d_star_ms": d_star_ms,
            "age_margin_ms": (
                None if d_star_ms is None or age_max_ms is None else d_star_ms - age_max_ms
            ),
            "lateness_now_us": _per(self.lateness_now_ns, 1e3),
            "lateness_max_us": _per(self.lateness_max_ns, 1e3),
            "deadline_misses": self.deadline_misses,
            "states_without_command": self.unanswered,
            "max_abs_v": self.max_v,
            "max_abs_omega": self.max_w,
            "view_backlog": int(backlog),
            "verdict": outcome,
            "reasons": reasons,
        }
        return {k: v for k, v in figures.items() if v is not None}


def _per(ns: int | None, unit_ns: float) -> float | None:
    """``ns`` in units of ``unit_ns`` (at least 0), None while unknown."""
    return None if ns is None else max(0.0, ns / unit_ns)

"""The live view's timing figures (schema ``hil.LiveTiming`` in :mod:`hil.schemas`; docs/live.md).

Live estimates from the messages as the view receives them, for a person watching; the run's own
figures (docs/realtime.md) are measured afterwards from the hop logs. Command age at a State: its
sample time - the sample time of the newest TorqueCommand the view had seen when the State
arrived (before the first command, - the first State's); lateness: a command's compute start -
the previous command's - Ts (>= 0); states without command: of the States the controller was
meant to answer (every State; one per control period when a periodic controller runs below the
plant's sample rate, as docs/realtime.md counts ``samples_without_command``), those no command
named within 0.1 s + Ts of their arrival. The verdict so far is the final verdict's function,
:func:`hil.verdict.judge_evidence`, on these figures: the limits of (2) from the peaks of |v|
and |ω|, D against D*, the States without a command against the same threshold. A run whose
final verdict is FAIL never shows INCONCLUSIVE live for the same evidence (without the stalls'
owners all of D is the system's). Missed slots and lost messages need the hop logs: only the
final verdict judges them.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

from hil import schemas
from hil.verdict import Evidence, control_slot, judge_evidence
from protocol.hoplog import NO_STAMP
from protocol.messages import State, Status, TorqueCommand

UNANSWERED_AFTER_NS = 100_000_000  # beyond the control period: the tick's own wait


@dataclass(frozen=True)
class Bounds:
    """What the figures are judged against: D* (None: no certificate), Ts, limits (2); the
    plant's sample period and whether the controller ticks periodically (then, with a longer
    Ts, it is meant to answer one State per control period)."""

    d_star_s: float | None
    ts_s: float
    phi1: float
    phi2: float
    sensor_ts_s: float | None = None  # None: the control period
    periodic: bool = True

    @property
    def one_per_period(self) -> bool:
        return self.periodic and self.sensor_ts_s is not None and self.sensor_ts_s < self.ts_s


class LiveTiming:
    """Fed States, commands and Statuses in arrival order (by one thread); :meth:`snapshot`."""

    def __init__(self, bounds: Bounds) -> None:
        self.bounds = bounds
        self.ts_ns = round(bounds.ts_s * 1e9)
        self.states = self.commands = 0
        self.first_state_ns: int | None = None
        self.first_recv_ns: int | None = None
        self.epoch_ns: int | None = None  # the run's t = 0 (the controller's Status)
        self.origin_ns: int | None = None  # the control slots' grid, once known
        self.in_force_sample_ns: int | None = None  # of the newest command seen
        self.age_now_ns: int | None = None
        self.age_max_ns: int | None = None
        self.last_compute_ns: int | None = None
        self.lateness_now_ns: int | None = None
        self.lateness_max_ns: int | None = None
        self.deadline_misses: int | None = None
        self.unanswered = 0
        self.judged = 0  # States (or control slots) answered or given up on
        self.pending: OrderedDict[int, int] = OrderedDict()  # state seq or slot -> arrival
        self.max_v = self.max_w = 0.0

    def _key(self, seq: int, sample_ns: int) -> int:
        """What one answer covers: the State itself, or its control slot (one State per
        control period; hil.verdict.control_slot, on the controller's nominal grid
        half a period after the epoch)."""
        if not self.bounds.one_per_period:
            return seq
        if self.origin_ns is None:  # fixed at first use: keys never move under a pending slot
            epoch = self.epoch_ns if self.epoch_ns is not None else self.first_state_ns or 0
            self.origin_ns = epoch + self.ts_ns // 2
        return int(control_slot(sample_ns, self.origin_ns, self.ts_ns))

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
        self.pending.setdefault(self._key(st.seq, st.sample_time_ns), recv_ns)
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
            late = max(0, gap - self.ts_ns)
            self.lateness_now_ns = late
            self.lateness_max_ns = max(self.lateness_max_ns or 0, late)
        self.last_compute_ns = cmd.compute_start_ns
        if (
            sample != NO_STAMP
            and self.pending.pop(self._key(cmd.state_seq, sample), None) is not None
        ):
            self.judged += 1

    def on_status(self, st: Status) -> None:
        if st.role == "controller" and "deadline_misses" in st.counters:
            self.deadline_misses = int(st.counters["deadline_misses"])
        if st.role == "controller" and int(st.counters.get("epoch_ns") or 0) > 0:
            self.epoch_ns = int(st.counters["epoch_ns"])

    def _expire(self, now_ns: int) -> None:
        while self.pending:
            key, arrived = next(iter(self.pending.items()))
            if now_ns - arrived < UNANSWERED_AFTER_NS + self.ts_ns:
                break
            del self.pending[key]
            self.unanswered += 1
            self.judged += 1

    def evidence(self) -> Evidence:
        """The figures so far as the verdict reads them (hil.verdict.Evidence)."""
        b = self.bounds
        age = self.age_max_ns
        return Evidence(
            peaks={"v": self.max_v, "omega": self.max_w},
            limits={"phi1": b.phi1, "phi2": b.phi2},
            d_max_s=None if age is None else age / 1e9,
            d_star_s=b.d_star_s,
            samples_without_command=self.unanswered,
            samples_judged=self.judged,
        )

    def verdict(self) -> tuple[str, str]:
        """(outcome, reasons) so far: :func:`hil.verdict.judge_evidence` on :meth:`evidence`."""
        if self.states == 0:
            return "WAITING", "no State yet"
        v = judge_evidence(self.evidence())
        return v.outcome, "; ".join(v.reasons)

    def snapshot(self, now_ns: int, backlog: int = 0) -> schemas.Json:
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

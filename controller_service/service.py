"""The controller service: the scenario's law (7)-(10)/(19) on the wall clock, over Zenoh and CAN.

Functional core, thin shell:

- :class:`ControlCore` (pure, no I/O, explicit time): one sample in, torques out. It evaluates
  the reference (3) at the law clock ``t``, calls ``Controller.update`` (memory passed
  explicitly) through :func:`controller_service.laws.guard.checked_update`, so a law that
  raises, returns the wrong type or a non-finite torque raises ``LawFaultError``; a finite
  torque is clamped to |tau1| <= varpi1, |tau2| <= varpi2 (2).
- On a law fault the service stops commanding (no command is sent for that sample or after
  it), writes ``law_fault.json`` (:data:`protocol.hoplog.LAW_FAULT_FILE`) into the run folder,
  publishes its Status as a fault (``state = "law_fault_<kind>"``, ``STATUS_FAULT``) and the
  process exits with :data:`protocol.hoplog.LAW_FAULT_EXIT`.
- :class:`ControllerService` (the shell): receives State on Zenoh, wakes on absolute deadlines
  (``trigger = "periodic"``) or on each fresh state (``"on_state"``, and lockstep), publishes
  each command on every command path it has (:mod:`controller_service.command_paths`: a
  TorqueCommand on Zenoh, Set_Input_Torque frames on the CAN bus after the drive lifecycle),
  Telemetry and Status, and keeps the stale-state watchdog. Every hop is time-stamped into
  ``controller.hoplog`` (:mod:`protocol.hoplog`), streamed to disk while the run goes on;
  :mod:`hil.measure` turns it into the timing figures.

The law clock ``t`` is the state's sample time since the run's epoch (an ns value shared by both
processes); in lockstep it is the virtual time ``state_seq * Ts`` so the law sees exactly the
simulator's sample times.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller_service.command_paths import (
    NOT_SENT,
    CanCommandPath,
    CommandPath,
    ZenohCommandPath,
)
from controller_service.laws.base import Controller, Limits, RobotState
from controller_service.laws.guard import LawFault, LawFaultError, checked_update
from controller_service.tick_phase import PhaseLearner
from protocol import keys
from protocol.faults import Faults
from protocol.hoplog import (
    CONTROLLER_HOPLOG,
    CONTROLLER_TABLES,
    LAW_FAULT_EXIT,
    LAW_FAULT_FILE,
    NO_SEQ,
    NO_STAMP,
    TICK_NO_SEND,
    CmdPath,
    HopLogWriter,
    StateRxRow,
    TickRow,
    crashed_log,
)
from protocol.messages import (
    FLAG_STOP,
    FLAG_WATCHDOG_ZERO,
    STATUS_FAULT,
    STATUS_WATCHDOG_TRIPPED,
    State,
    Status,
    Telemetry,
    TorqueCommand,
    decode_counted,
    encode,
)
from protocol.rejections import RejectionCounter
from protocol.sequence import SequenceTracker
from protocol.settings import RunSettings, period_ns
from runtime.realtime import DeadlineClock, SchedulingReport, setup_scheduling
from runtime.tap import Tap

TELEMETRY_FIELDS = ("xe", "ye", "theta_e", "xi", "v_tilde", "w_tilde", "z1", "z2", "eta")


@dataclass
class ControlCore:
    """One robot's law at sample times: explicit memory, guarded torques (2)."""

    controller: Controller
    reference: Any
    ts: float  # s, the control period T_s (the law's nominal dt)
    limits: Limits
    rejections: RejectionCounter = field(default_factory=RejectionCounter)
    memory: Any = None

    def __post_init__(self) -> None:
        if self.memory is None:
            self.memory = self.controller.initial_memory(None)

    def step(self, t: float, state: RobotState) -> tuple[float, float, dict[str, float]]:
        ref = self.reference.sample(t)
        out, self.memory = checked_update(self.controller, t, self.ts, state, ref, self.memory)
        tau1, tau2 = self.guard(out.tau1, out.tau2)
        return tau1, tau2, dict(out.telemetry)

    def guard(self, tau1: Any, tau2: Any) -> tuple[float, float]:
        """Non-finite -> 0 (counted; :meth:`step` raises before, this is the last line);
        finite -> clamped to the limits (2) (counted)."""
        a = float(tau1)
        b = float(tau2)
        lim = self.limits
        if not math.isfinite(a):
            self.rejections.count("non_finite_tau1")
            a = 0.0
        if not math.isfinite(b):
            self.rejections.count("non_finite_tau2")
            b = 0.0
        if abs(a) > lim.varpi1:
            self.rejections.count("clamped_tau1")
            a = math.copysign(lim.varpi1, a)
        if abs(b) > lim.varpi2:
            self.rejections.count("clamped_tau2")
            b = math.copysign(lim.varpi2, b)
        return a, b


@dataclass
class Received:
    state: State
    recv_ns: int


class ControllerService:
    """The shell around :class:`ControlCore` (see the module docstring)."""

    def __init__(
        self,
        core: ControlCore,
        session: Any,
        robot_id: str,
        epoch_ns: int,
        ts: float,
        trigger: str = "periodic",
        lockstep: bool = False,
        state_timeout: float = 0.05,
        can_path: CanCommandPath | None = None,
        law_name: str = "unified",
        spin_ns: int = 0,
        hoplog: HopLogWriter | None = None,
        faults: Faults | None = None,
        tick_phase: str = "half",
    ) -> None:
        from runtime.zsession import payload_bytes, publisher

        self.core = core
        self.session = session
        self.robot_id = robot_id
        self.epoch_ns = int(epoch_ns)
        self.period_ns = period_ns(ts)
        self.trigger = "on_state" if lockstep else trigger
        self.lockstep = lockstep
        self.state_timeout_ns = int(state_timeout * 1e9)
        self.can_path = can_path
        self.law_name = law_name
        self.spin_ns = spin_ns
        self.rejections = RejectionCounter()
        self.tracker = SequenceTracker()
        self._payload = payload_bytes
        self.faults = faults or Faults()
        # Observers read what this service sent from its tap (protocol.tap), not the loop's keys.
        self.tap = Tap(session, robot_id, "controller")
        self.zenoh = ZenohCommandPath(session, robot_id, self.faults, self.tap)
        self.zenoh.epoch_ns = self.epoch_ns
        self.paths: list[CommandPath] = [self.zenoh] if can_path is None else [self.zenoh, can_path]
        self._pub_tel = publisher(session, keys.telemetry_key(robot_id))
        self._pub_status = publisher(session, keys.status_key(robot_id))
        self._newest: Received | None = None
        self._last_used_seq = -1
        self._last_fresh_ns = time.monotonic_ns()
        self._stale = False
        self.stale_entries = 0
        self._cmd_seq = 0
        self._tel_seq = 0
        self._status_seq = 0
        self._lock = threading.Lock()
        if hoplog is None:
            raise ValueError("the controller service needs a hop log")
        self.hoplog = hoplog
        self.scheduling = SchedulingReport()
        self.clock: DeadlineClock | None = None
        self.cycles = 0
        self.states_seen = 0
        self.law_fault: LawFault | None = None  # set once: no command is sent after it
        learn = tick_phase == "auto" and self.trigger == "periodic"
        self.phase_learner = PhaseLearner(self.period_ns) if learn else None
        self._sub = session.declare_subscriber(keys.state_key(robot_id), self._on_state)

    # --- receive ------------------------------------------------------------------------
    def _on_state(self, sample: Any) -> None:
        recv_ns = time.monotonic_ns()
        payload = self._payload(sample)
        msg = decode_counted(
            payload,
            self.rejections,
            State,
            lambda why: self.tap.rejected(keys.STATE, recv_ns, payload, why),
        )
        if msg is None:
            return
        if msg.robot_id != self.robot_id:
            self.rejections.count("wrong_robot")
            self.tap.rejected(keys.STATE, recv_ns, payload, "wrong_robot")
            return
        with self._lock:
            self._take_state(msg, recv_ns)
        if self.trigger == "on_state":
            # After the command left; the next State is a period away.
            self.tap.flush_if_due(time.monotonic_ns())

    def _take_state(self, msg: State, recv_ns: int) -> None:
        """A decoded State of this robot (under the service's lock): logged, then used."""
        verdict = self.tracker.observe(msg.seq)
        self.hoplog.append(
            "state_rx",
            StateRxRow(
                seq=msg.seq,
                sample_ns=msg.sample_time_ns,
                send_ns=msg.send_time_ns,
                recv_ns=recv_ns,
                verdict=verdict.code,
            ),
        )
        if not verdict.fresh:
            if self.lockstep and msg.seq == self._last_used_seq:
                # The plant re-sent the state because our command was lost: answer again
                # with the same command (same seq), never recompute (memory moved on).
                self.zenoh.resend_last()
            return
        self.states_seen += 1
        if self.phase_learner is not None:
            self.phase_learner.state(recv_ns - msg.sample_time_ns, recv_ns - msg.send_time_ns)
        rec = Received(msg, recv_ns)
        self._newest = rec
        if self.trigger == "on_state":
            self._cycle(msg.seq, recv_ns, recv_ns, rec)

    # --- one control cycle -----------------------------------------------------------------
    def _law_time(self, st: State) -> float:
        if self.lockstep:
            return st.seq * self.core.ts
        return (st.sample_time_ns - self.epoch_ns) / 1e9

    def _cycle(
        self, k: int, deadline_ns: int, wake_ns: int, rec: Received | None, skipped: int = 0
    ) -> None:
        flags = 0
        if self.law_fault is not None:  # the law failed: nothing is commanded any more
            return
        if rec is not None and rec.state.seq > self._last_used_seq:
            st = rec.state
            self._last_used_seq = st.seq
            self._last_fresh_ns = rec.recv_ns
            if self._stale:
                self._stale = False
            c0 = time.monotonic_ns()
            try:
                tau1, tau2, tel = self.core.step(
                    self._law_time(st), RobotState(st.x, st.y, st.theta, st.v, st.omega)
                )
            except LawFaultError as exc:
                self.law_fault = exc.fault
                self.hoplog.append("ticks", self._idle_tick(k, deadline_ns, wake_ns, skipped))
                return
            c1 = time.monotonic_ns()
            if self.phase_learner is not None:
                self.phase_learner.compute(c1 - c0)
            state_seq, sample_ns, send_state_ns, recv_ns = (
                st.seq,
                st.sample_time_ns,
                st.send_time_ns,
                rec.recv_ns,
            )
        elif wake_ns - self._last_fresh_ns > self.state_timeout_ns:
            if not self._stale:
                self._stale = True
                self.stale_entries += 1
            flags |= FLAG_WATCHDOG_ZERO
            tau1 = tau2 = 0.0
            tel = {}
            c0 = c1 = time.monotonic_ns()
            state_seq = max(self._last_used_seq, 0)
            sample_ns = send_state_ns = recv_ns = NO_STAMP
        else:
            # No new sample and not yet stale: the last command stands. The tick is still
            # logged, so wake-up lateness and jitter cover every cycle.
            self.hoplog.append("ticks", self._idle_tick(k, deadline_ns, wake_ns, skipped))
            return
        cmd_seq = self._cmd_seq
        zsend, csend, fault_flags = self._publish(state_seq, sample_ns, c0, tau1, tau2, flags, tel)
        self.cycles += 1
        self.hoplog.append(
            "ticks",
            TickRow(
                k=k,
                deadline_ns=deadline_ns,
                wake_ns=wake_ns,
                skipped=skipped,
                state_seq=state_seq,
                state_sample_ns=sample_ns,
                state_send_ns=send_state_ns,
                state_recv_ns=recv_ns,
                compute_start_ns=c0,
                compute_end_ns=c1,
                zenoh_send_ns=zsend,
                can_send_ns=csend,
                cmd_seq=cmd_seq,
                tau1=tau1,
                tau2=tau2,
                flags=flags | fault_flags,
            ),
        )

    @staticmethod
    def _idle_tick(k: int, deadline_ns: int, wake_ns: int, skipped: int) -> TickRow:
        """The row of a tick that sent nothing."""
        return TickRow(
            k=k,
            deadline_ns=deadline_ns,
            wake_ns=wake_ns,
            skipped=skipped,
            state_seq=NO_SEQ,
            state_sample_ns=NO_STAMP,
            state_send_ns=NO_STAMP,
            state_recv_ns=NO_STAMP,
            compute_start_ns=NO_STAMP,
            compute_end_ns=NO_STAMP,
            zenoh_send_ns=NO_STAMP,
            can_send_ns=NO_STAMP,
            cmd_seq=NO_SEQ,
            tau1=0.0,
            tau2=0.0,
            flags=TICK_NO_SEND,
        )

    def _publish(
        self,
        state_seq: int,
        sample_ns: int,
        c0: int,
        tau1: float,
        tau2: float,
        flags: int,
        tel: dict[str, Any],
    ) -> tuple[int, int, int]:
        """Send one command on every command path; returns the Zenoh and CAN send times
        (NO_STAMP: not sent on that path) and the tick flags of the [faults] injections."""
        send_ns = time.monotonic_ns()
        cmd = TorqueCommand(
            self.robot_id,
            self._cmd_seq,
            state_seq,
            sample_ns,
            c0,
            send_ns,
            tau1,
            tau2,
            self.law_name,
            flags,
        )
        self._cmd_seq += 1
        sent = {p.path: p.send(cmd) for p in self.paths}
        zenoh, can = sent.get(CmdPath.ZENOH, NOT_SENT), sent.get(CmdPath.CAN, NOT_SENT)
        if tel and all(n in tel for n in TELEMETRY_FIELDS):
            try:
                payload = encode(
                    Telemetry(
                        self.robot_id,
                        self._tel_seq,
                        sample_ns,
                        *(float(tel[n]) for n in TELEMETRY_FIELDS),
                    )
                )
                self._pub_tel.put(payload)
                self.tap.sent(keys.TELEMETRY, time.monotonic_ns(), payload)
                self._tel_seq += 1
            except ValueError:
                self.rejections.count("telemetry_unencodable")
        return zenoh.send_ns, can.send_ns, zenoh.flags | can.flags

    def publish_status(self, state: str = "running") -> None:
        flags = STATUS_WATCHDOG_TRIPPED if self._stale else 0
        if self.can_path is not None and self.can_path.lifecycle.fault_reason:
            flags |= STATUS_FAULT
        if self.law_fault is not None:
            flags |= STATUS_FAULT
            state = f"law_fault_{self.law_fault.kind}"
        counters = {
            "epoch_ns": self.epoch_ns,  # a restarted peer joins the run with it
            "cycles": self.cycles,
            "states": self.states_seen,
            "stale_entries": self.stale_entries,
            "rejections": self.rejections.total + self.core.rejections.total,
            "deadline_misses": self.clock.misses if self.clock else 0,
            "sched_fifo": int(self.scheduling.policy == "SCHED_FIFO"),
            "mlockall": int(self.scheduling.mlockall),
            "gc_frozen": int(self.scheduling.gc_frozen),
            # a controller started again into a running run (hil run then follows it on)
            "restarted": int(getattr(self, "restarted", False)),
        }
        if self.can_path is not None:
            counters["can_active"] = int(self.can_path.active)
        self.hoplog.counters(self.final_counters())
        msg = Status(
            self.robot_id,
            self._status_seq,
            time.monotonic_ns(),
            "controller",
            state,
            flags,
            counters,
        )
        self._status_seq += 1
        self._pub_status.put(encode(msg))

    # --- main loop -----------------------------------------------------------------------
    def run(self, stop: Any, end_ns: int | None, scheduling: SchedulingReport) -> None:
        """Run until ``stop`` is truthy or ``end_ns`` (monotonic) passes."""
        self.scheduling = scheduling
        status_every_ns = 200_000_000
        self._last_fresh_ns = max(self._last_fresh_ns, self.epoch_ns)
        next_status = time.monotonic_ns()
        if self.trigger == "periodic":
            # On the epoch's grid so the controller's ticks keep a fixed phase to the plant's
            # sensor ticks (no drift between the two processes), half a period after the
            # plant's sample: the state (sent ~0.2-0.5 ms after its sample on a loaded host) is
            # then in hand at the tick in most cycles. Slots count from the epoch, so a
            # controller restarted mid-run continues the same numbering.
            now = time.monotonic_ns()
            origin = self.epoch_ns + self.period_ns // 2
            first = max(0, -(-(now - origin) // self.period_ns))
            self.clock = DeadlineClock(self.period_ns, origin, self.spin_ns, first_k=first)
            while self._going(stop, end_ns):
                tick = self.clock.next()
                self._cycle(tick.k, tick.deadline_ns, tick.wake_ns, self._newest, tick.skipped)
                self.tap.flush_if_due(tick.wake_ns)  # the command has left
                if self.phase_learner is not None:
                    self._rephase(tick.k)
                if tick.wake_ns >= next_status:
                    next_status = tick.wake_ns + status_every_ns
                    self.publish_status()
        else:
            while self._going(stop, end_ns):
                time.sleep(0.01)
                now = time.monotonic_ns()
                if not self.lockstep and now - self._last_fresh_ns > self.state_timeout_ns:
                    with self._lock:
                        self._cycle(-1, now, now, None)
                    self.tap.flush_if_due(now)  # no State comes: nothing else flushes
                if now >= next_status:
                    next_status = now + status_every_ns
                    self.publish_status()
        self.publish_status("stopped")

    def _going(self, stop: Any, end_ns: int | None) -> bool:
        """The loop goes on: no stop asked, the end not reached, the law has not failed."""
        if stop or self.law_fault is not None:
            return False
        return end_ns is None or time.monotonic_ns() < end_ns

    def _rephase(self, k: int) -> None:
        """Move the ticks to the learnt phase (controller_service.tick_phase), once: from slot
        k + 1 on, due at epoch + phase + slot Ts. The shift is under a period either way, so
        the next deadline stays ahead and no slot is skipped; it is logged so that the period
        jitter does not count it."""
        assert self.phase_learner is not None and self.clock is not None
        choice = self.phase_learner.choice()
        if choice is None:
            return
        origin = self.epoch_ns + choice.phase_ns
        shift = origin - self.clock.start_ns
        self.clock.start_ns = origin
        self.phase_learner = None
        self.hoplog.update_meta(
            {**choice.as_meta(), "tick_phase_from_k": k + 1, "tick_phase_shift_ns": shift}
        )

    def stop_listening(self) -> None:
        """No more States: what the hop log's last counters say was refused is what the tap
        handed on (a stranger's puts go on after the run)."""
        with contextlib.suppress(Exception):  # the session may be gone on the way out
            self._sub.undeclare()

    def send_stop(self) -> None:
        """A last zero command flagged STOP, so the plant idles at once."""
        self._publish(max(self._last_used_seq, 0), 0, time.monotonic_ns(), 0.0, 0.0, FLAG_STOP, {})

    def continue_after(self, next_cmd_seq: int) -> None:
        """A restart: number commands on from the crashed predecessor's last one."""
        self._cmd_seq = int(next_cmd_seq)
        self.restarted = True

    def final_counters(self) -> dict[str, Any]:
        """The service's counters (the hop log's footer, and its periodic snapshots)."""
        return {
            "deadline_misses": self.clock.misses if self.clock else 0,
            "skipped_slots": self.clock.skipped if self.clock else 0,
            "state_counts": self.tracker.counts.as_dict(),
            "rejections": {**self.rejections.snapshot(), **self.core.rejections.snapshot()},
            "stale_entries": self.stale_entries,
            "commands_sent": self._cmd_seq,
            "restarted": getattr(self, "restarted", False),
            "injected": {
                **{f"command_{k}": v for k, v in self.zenoh.injected.items()},
                "can_bus_off_frames": self.can_path.injected_bus_off if self.can_path else 0,
            },
            "scheduling": self.scheduling.as_dict(),
            "tap": self.tap.counters(),
            "can": None
            if self.can_path is None
            else {
                "phase": self.can_path.lifecycle.phase.value,
                "fault": self.can_path.lifecycle.fault_reason,
                "frames_sent": self.can_path.sent_frames,
                "arm_sends": self.can_path.arm_sends,
                "rearms": self.can_path.rearms,
                "send_errors": self.can_path.send_errors,
                "rejections": self.can_path.lifecycle.rejections.snapshot(),
            },
        }


def _open_hoplog(s: RunSettings, previous: Any) -> HopLogWriter:
    """The controller's hop log; a predecessor's crashed log (``previous``) is continued."""
    return HopLogWriter(
        Path(s.out_dir) / CONTROLLER_HOPLOG,
        "controller",
        CONTROLLER_TABLES,
        {
            "robot_id": s.robot_id,
            "period_ns": period_ns(s.ts),
            "trigger": "on_state" if s.lockstep else s.trigger,
            "lockstep": s.lockstep,
            "cmd_path": s.cmd_path,
            "state_timeout_s": s.state_timeout,
            "epoch_ns": s.epoch_ns,
            "tick_phase": s.tick_phase,
        },
        append=previous is not None,
    )


def _open_can_path(s: RunSettings, hoplog: HopLogWriter, faults: Faults) -> CanCommandPath | None:
    """The CAN command path to the drives when the run has a CAN bus (None otherwise)."""
    bus = s.open_can_bus()
    if bus is None:
        return None
    from protocol.can.drive_profile import HostLifecycle

    cs = s.can_settings()
    geom, limit = s.motor_limit()
    lifecycle = HostLifecycle(
        node_right=cs.node_right,
        node_left=cs.node_left,
        heartbeat_timeout=cs.heartbeat_timeout,
        torque_limit=limit,
    )
    return CanCommandPath(bus, lifecycle, geom, hoplog, faults)


def write_law_fault(folder: Path, fault: LawFault) -> Path:
    """law_fault.json in the run folder, whole or not at all (written, then renamed)."""
    path = folder / LAW_FAULT_FILE
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(fault.to_dict(), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


def _law_fault_exit(folder: Path, fault: LawFault) -> int:
    """law_fault.json written, the sentence and the traceback said: the exit code that tells
    ``hil run`` the law failed (it will not come back)."""
    write_law_fault(folder, fault)
    print(f"law fault: {fault.sentence()}", flush=True)
    if fault.traceback:
        print(fault.traceback, end="", flush=True)
    return LAW_FAULT_EXIT


def _first_free_cmd_seq(previous: Any, ts: float) -> int:
    """After a restart: past the predecessor's last logged command number, plus a second's
    worth of numbers (it may have sent commands it had not logged yet: its last chunk, up to
    the log's flush interval), so no number is ever reused."""
    at = CONTROLLER_TABLES["ticks"].index("cmd_seq")
    seqs = [r[at] for r in previous.rows.get("ticks", []) if r[at] >= 0]
    return max(seqs, default=-1) + 1 + math.ceil(1.0 / ts - 1e-9)


def main_from_settings(settings_path: str, *more: str) -> int:
    """Entry of ``python -m controller_service SETTINGS.json [MORE.json ...]`` (``hil``
    resolved the run into that file: :class:`protocol.settings.RunSettings`); several files:
    one process hosts each of those robots' controllers (:func:`main_group`)."""
    from runtime.realtime import restore_gc
    from runtime.signals import stop_on_signals
    from runtime.zsession import check_credentials, open_session

    if more:
        return main_group([settings_path, *more])
    s = RunSettings.load(settings_path)
    s.validate()
    check_credentials(s.zenoh_endpoint, s.zenoh_mode)  # a bad credentials file: exit before a log
    session = open_session(s.zenoh_endpoint, mode=s.zenoh_mode)
    try:
        parts = build_service(s, session)
    except LawFaultError as exc:  # the law could not be built here: its fault, said as such
        session.close()
        return _law_fault_exit(Path(s.out_dir), exc.fault)
    if parts.svc.epoch_ns == 0:  # the start will be announced on the plant's clock: relate it
        parts.clock.wait_first()
    try:
        with stop_on_signals() as stop:
            # Scheduling first, readiness after: the set-up (mlockall, a full collection, the
            # GC frozen) takes tens of ms, which must not eat into the run's first periods.
            sched = setup_scheduling(s.scheduling, cpu=s.cpu_controller, idle=s.idle)
            try:
                return _run_service(s, parts, stop, sched)
            finally:
                restore_gc()
    finally:
        parts.clock.close()
        session.close()


def main_group(paths: list[str]) -> int:
    """Several robots' controllers in one process (a fleet on few cores: runtime.group): each
    its own :class:`ControllerService` (its keys, law memory, hop log in its own run folder,
    clock probe, deadlines on its own epoch) in its own thread; the session, the scheduling
    and the signals shared."""
    from runtime.group import load_group, run_threads
    from runtime.realtime import restore_gc
    from runtime.signals import stop_on_signals
    from runtime.zsession import open_session

    settings = load_group(paths)
    first = settings[0]
    session = open_session(first.zenoh_endpoint, mode=first.zenoh_mode)
    built = []
    for s in settings:
        try:
            built.append(build_service(s, session))
        except LawFaultError as exc:  # that robot's law; the process serves them all
            session.close()
            return _law_fault_exit(Path(s.out_dir), exc.fault)
    try:
        for parts in built:
            if parts.svc.epoch_ns == 0:
                parts.clock.wait_first()
        with stop_on_signals() as stop:
            # Once, before the threads (they inherit the policy and the CPU).
            sched = setup_scheduling(first.scheduling, cpu=first.cpu_controller, idle=first.idle)
            try:
                bodies = [
                    lambda s=s, p=p: _run_service(s, p, stop, sched)
                    for s, p in zip(settings, built, strict=True)
                ]
                return run_threads([s.robot_id for s in settings], bodies)
            finally:
                restore_gc()
    finally:
        for parts in built:
            parts.clock.close()
        session.close()


@dataclass
class Parts:
    """One robot's controller as built before its run: the service, its start gate, hop log,
    CAN path and clock probe (started)."""

    svc: ControllerService
    gate: Any
    hoplog: HopLogWriter
    can_path: CanCommandPath | None
    clock: Any


def build_service(s: RunSettings, session: Any) -> Parts:
    """One robot's controller on ``session``, its clock probe started."""
    from controller_service.from_settings import build_law
    from runtime.clocksync import CLOCK_FILE, ClockProbe
    from runtime.startgate import StartGate

    controller, reference, memory, law_name = build_law(s)
    core = ControlCore(controller, reference, s.ts, s.limits_value, memory=memory)
    faults = Faults.of(s.faults)
    # A predecessor that crashed mid-run left its log open: this is a restart, which continues
    # that log, its epoch and its command numbering (the plant's tracker sees no gap).
    previous = crashed_log(Path(s.out_dir) / CONTROLLER_HOPLOG)
    hoplog = _open_hoplog(s, previous)
    can_path = _open_can_path(s, hoplog, faults)
    epoch_ns = s.epoch_ns or (int(previous.meta["epoch_ns"]) if previous is not None else 0)
    gate = StartGate(session, s.robot_id, "controller")
    if can_path is not None:
        can_path.start()  # arm the drives while waiting: the plant answers before the epoch
    svc = ControllerService(
        core,
        session,
        s.robot_id,
        epoch_ns,
        s.ts,
        trigger=s.trigger,
        lockstep=s.lockstep,
        state_timeout=s.state_timeout,
        can_path=can_path,
        law_name=law_name,
        spin_ns=int(s.spin_us * 1000),
        hoplog=hoplog,
        faults=faults,
        tick_phase=s.tick_phase,
    )
    if previous is not None:
        svc.continue_after(_first_free_cmd_seq(previous, s.ts))
    # The offset to the plant's clock, off the real-time thread (started before its scheduling).
    clock = ClockProbe(session, s.robot_id, Path(s.out_dir) / CLOCK_FILE).start()
    return Parts(svc, gate, hoplog, can_path, clock)


def _run_service(s: RunSettings, parts: Parts, stop: Any, sched: SchedulingReport) -> int:
    """Wait for the run's start (unless the epoch is known; announced on the plant's clock,
    converted with the clock probe's estimate), run until stopped, close the robot's own
    parts (not the session)."""
    from runtime.clocksync import epoch_on_local_clock

    svc, hoplog, can_path = parts.svc, parts.hoplog, parts.can_path
    svc.scheduling = sched
    try:
        epoch_ns = svc.epoch_ns
        if epoch_ns == 0:
            got = parts.gate.wait(stop, timeout=s.start_timeout, ready=svc.zenoh.matched)
            if got is None:
                print("no start: stopped or start-gate timeout", flush=True)
                return 1
            epoch_ns = svc.epoch_ns = epoch_on_local_clock(got, parts.clock)
        hoplog.update_meta({"epoch_ns": epoch_ns})
        svc.zenoh.epoch_ns = epoch_ns
        if can_path is not None:
            can_path.epoch_ns = epoch_ns
        end_ns = None if s.lockstep else epoch_ns + int((s.duration + 2.0) * 1e9)
        print(f"running epoch_ns={epoch_ns} scheduling={sched.policy}", flush=True)
        svc.run(stop, end_ns, sched)
        if svc.law_fault is not None:
            return _law_fault_exit(Path(s.out_dir), svc.law_fault)
    finally:
        svc.stop_listening()
        with contextlib.suppress(Exception):  # the session may be gone on the way out
            svc.send_stop()
        svc.tap.close()  # the stop command too; a closed session is counted, not raised
        if can_path is not None:
            can_path.close()
        hoplog.close(svc.final_counters())
    return 0

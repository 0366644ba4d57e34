"""The plant emulator: model (1) in real time (or in lockstep), commands from Zenoh or CAN.

Functional core, thin shell:

- :class:`PlantCore` (pure, explicit time): the robot of :mod:`plant_emulator.dynamics`
  integrated *lazily* up to each event's time (a command landing, a sensor tick) in RK4 steps of
  at most ``h`` (default Ts/10), with the scenario's disturbance and actuator lag, holding the
  newest command; it tracks the extremes and violations of (2) over every plant step.
- :class:`PlantService` (the shell): publishes State at ``sensor_rate`` on absolute deadlines
  and orders the events between (landings, the command timeout). Commands come from two
  sources (:mod:`plant_emulator.commands`): TorqueCommand on Zenoh and Set_Input_Torque frames
  on CAN (two virtual ODrives, :mod:`plant_emulator.odrive`, on the bus edge of
  :mod:`plant_emulator.can_drives`, which answers requests and sends their cyclic frames at
  their own rates in every mode); the service lands ONE path's commands (``cmd_path``) and the
  other is stamped as a shadow; a command timeout on the applied path zeroes the torque;
  ``[timing] delay`` and ``jitter`` are injected on the applied path (newest by sequence
  number wins). Every sample, command arrival and landing is time-stamped
  into ``plant.hoplog``
  (:mod:`protocol.hoplog`), streamed to disk while the run goes on.
- Lockstep (:meth:`PlantService.run_lockstep`): State k is sent at virtual time t_k = k Ts,
  the plant waits for the command with ``state_seq == k`` and applies it over
  [t_k + delay, ...) exactly as the offline simulator does, so the trajectory equals it.
"""

from __future__ import annotations

import contextlib
import math
import random
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from plant_emulator.can_drives import CanDrives
from plant_emulator.commands import Arrival, CanCommands, CommandSource, ZenohCommands
from plant_emulator.disturbances import Disturbance
from plant_emulator.drive_plant import DrivePlant
from plant_emulator.dynamics import NO_DRAG, Drag, Extremes, PlantState
from plant_emulator.sampled import Command, Hold, Plant, advance_period, integrate_span
from plant_emulator.sensors import Sensor, measure
from protocol import keys
from protocol.faults import Faults, every_nth
from protocol.hoplog import (
    NO_NODE,
    PLANT_HOPLOG,
    PLANT_TABLES,
    SAMPLE_DROPPED,
    SAMPLE_DUPLICATED,
    SAMPLE_FEEDBACK_LOST,
    ApplyOutcome,
    ApplyRow,
    CmdPath,
    HopLogWriter,
    SampleRow,
    ZeroRow,
    crashed_log,
)
from protocol.messages import State as StateMsg
from protocol.messages import Status, TorqueCommand, encode
from protocol.rejections import RejectionCounter
from protocol.robot import Limits
from protocol.sequence import SequenceTracker
from protocol.settings import RunSettings, period_ns
from runtime.delay_line import DelayLine
from runtime.realtime import DeadlineClock, setup_scheduling, sleep_until_ns
from runtime.tap import Tap

# The part of each sensor period the plant integrates after its sample time (at most half the
# period); the rest is integrated before it, while the plant waits. A State then leaves about a
# wake-up and one or two RK4 steps after its sample, where integrating the whole period first
# took ~60 us of Python on this project's 2-vCPU guest.
INTEGRATE_AFTER_SAMPLE_NS = 150_000


@dataclass
class PlantCore:
    """Model (1) with held commands, advanced lazily in time (seconds since the epoch)."""

    state: PlantState
    h: float
    limits: Limits
    disturbance: Disturbance = field(default_factory=Disturbance)
    lag: float = 0.0
    seed: int | None = None
    drag: Drag = NO_DRAG
    t: float = 0.0
    cmd1: float = 0.0
    cmd2: float = 0.0
    extremes: Extremes = field(default_factory=Extremes)

    @property
    def plant(self) -> Plant:
        """The model's parameters as :mod:`plant_emulator.sampled` integrates them."""
        return Plant(self.h, self.disturbance, self.lag, self.seed, self.limits, self.drag)

    def advance_to(self, t1: float) -> None:
        """Integrate from ``self.t`` to ``t1`` with the held command (steps of at most h)."""
        if t1 <= self.t:
            return
        self.state = integrate_span(
            self.state, self.cmd1, self.cmd2, self.plant, self.t, t1, self.extremes
        )
        self.t = t1

    def lockstep_period(
        self, hold: Hold, k: int, m: int, offset: int, cmd1: float, cmd2: float, note: Any = None
    ) -> tuple[float, float]:
        """Period k of lockstep on the plant grid (t = j h, m steps a period): the command
        computed from State k, clamped to (2), leaves and lands ``offset`` steps after t_k; the
        plant runs :mod:`plant_emulator.sampled`'s step to t_(k+1), as the simulator does.
        Returns the torque applied at t_k (the held command, or the lagged actuator's)."""
        j0 = k * m
        self.t = j0 * self.h
        hold.send(k, j0 + offset, *self.clamp(cmd1, cmd2), note)
        hold.land(j0)
        applied = (hold.cmd1, hold.cmd2) if self.lag <= 0.0 else self.state[5:]
        self.state = advance_period(self.state, hold, self.plant, j0, j0 + m, self.extremes)
        self.cmd1, self.cmd2 = hold.cmd1, hold.cmd2
        self.t = (j0 + m) * self.h
        return applied

    def hold(self, cmd1: float, cmd2: float) -> None:
        """Hold a new command; clamped to (2) here, where commands are applied."""
        self.cmd1, self.cmd2 = self.clamp(cmd1, cmd2)

    def clamp(self, cmd1: float, cmd2: float) -> tuple[float, float]:
        """A command as the plant applies it: within (2), a non-finite torque zeroed."""
        lim = self.limits
        c1 = cmd1 if math.isfinite(cmd1) else 0.0
        c2 = cmd2 if math.isfinite(cmd2) else 0.0
        return max(-lim.varpi1, min(lim.varpi1, c1)), max(-lim.varpi2, min(lim.varpi2, c2))


@dataclass(order=True)
class Pending:
    """An arrival waiting to land at ``apply_ns`` (ties: in arrival order)."""

    apply_ns: int
    order: int
    source: CommandSource = field(compare=False)
    arrival: Arrival = field(compare=False)

    @property
    def recv_ns(self) -> int:
        return self.arrival.recv_ns


class DelayInjector:
    """Extra sample-to-apply delay on the applied path: constant ``delay`` plus ``jitter``
    (uniform in [0, jitter] or |normal| with std jitter), seeded; never makes commands
    overtake each other on the CAN path (frames keep bus order)."""

    def __init__(self, delay: float, jitter: float, kind: str, seed: int) -> None:
        self.delay_ns = int(delay * 1e9)
        self.jitter = jitter
        self.kind = kind
        self.rng = random.Random(seed)

    def extra_ns(self) -> int:
        if self.jitter <= 0.0:
            return self.delay_ns
        if self.kind == "normal":
            j = abs(self.rng.gauss(0.0, self.jitter))
        else:
            j = self.rng.uniform(0.0, self.jitter)
        return self.delay_ns + int(j * 1e9)


class PlantService:
    """The shell around :class:`PlantCore` (see the module docstring)."""

    def __init__(
        self,
        core: PlantCore,
        sensor: Sensor,
        session: Any,
        robot_id: str,
        epoch_ns: int,
        ts: float,
        sensor_ts: float,
        cmd_path: str = "zenoh",
        command_timeout: float = 0.05,
        injector: DelayInjector | None = None,
        can: CanCommands | None = None,
        hoplog: HopLogWriter | None = None,
        faults: Faults | None = None,
    ) -> None:
        from runtime.zsession import publisher

        self.core = core
        self.sensor = sensor
        self.session = session
        self.robot_id = robot_id
        self.epoch_ns = int(epoch_ns)
        self.ts = ts
        self.sensor_period_ns = period_ns(sensor_ts)
        self.applied_path = CmdPath.ZENOH if cmd_path == "zenoh" else CmdPath.CAN
        self.command_timeout_ns = int(command_timeout * 1e9)
        self.injector = injector or DelayInjector(0.0, 0.0, "uniform", 0)
        self.can = None if can is None else can.drives  # the edge's counters
        self.rejections = RejectionCounter()
        self.cmd_tracker = SequenceTracker()
        self._pub_state = publisher(session, keys.state_key(robot_id))
        self._pub_status = publisher(session, keys.status_key(robot_id))
        self.pending: list[Pending] = []
        self._order = 0
        self._last_cmd_recv_ns: int | None = None
        self.timed_out = False
        self.timeouts = 0
        if hoplog is None:
            raise ValueError("the plant service needs a hop log")
        self.hoplog = hoplog
        self.faults = faults or Faults()
        self.injected = {
            "state_drops": 0,
            "state_duplicates": 0,
            "delay_bursts": 0,
            "feedback_losses": 0,
        }
        # [faults] feedback_*: States held (or lost) on their way to the controller
        self.feedback = (
            DelayLine(self._put_state, "state-delay") if self.faults.feedback_held else None
        )
        self.samples = 0
        self.clock: DeadlineClock | None = None
        self._state_seq = 0
        self.resends = 0
        self._status_seq = 0
        # Observers read what this service sent from its tap (protocol.tap), not the loop's keys.
        self.tap = Tap(session, robot_id, "plant")
        self.zenoh = ZenohCommands(
            session,
            robot_id,
            hoplog,
            self.rejections,
            self.cmd_tracker,
            self.command_timeout_ns,
            self.tap,
        )
        self.sources: list[CommandSource] = [self.zenoh] if can is None else [self.zenoh, can]
        for source in self.sources:
            source.applied = source.path == self.applied_path
        # The source whose commands land (None: a CAN path without a bus, nothing lands).
        self.applied = next((x for x in self.sources if x.applied), None)

    # --- helpers ------------------------------------------------------------------------
    def _t(self, ns: int) -> float:
        return (ns - self.epoch_ns) / 1e9

    def _publish_state(self, sample_ns: int, k: int, wake_ns: int, log: bool = True) -> SampleRow:
        """Publish State k (unless a [faults] drop takes it); returns its log row, appended
        to the hop log unless ``log`` is false (lockstep patches it first)."""
        c = self.core
        meas = measure(self.sensor, c.state.robot_state(), k)
        send_ns = time.monotonic_ns()
        msg = StateMsg(
            self.robot_id,
            self._state_seq,
            sample_ns,
            send_ns,
            float(meas.x),
            float(meas.y),
            float(meas.theta),
            float(meas.v),
            float(meas.omega),
        )
        self._state_seq += 1
        flags = 0
        if self.faults.state_dropped(msg.seq, (sample_ns - self.epoch_ns) / 1e9):
            flags |= SAMPLE_DROPPED
            self.injected["state_drops"] += 1
        else:
            copies = 1
            if every_nth(msg.seq, self.faults.state_duplicate_every):
                flags |= SAMPLE_DUPLICATED
                self.injected["state_duplicates"] += 1
                copies = 2
            try:
                payload = encode(msg)
            except ValueError:
                self.rejections.count("state_unencodable")
                copies = 0
            if copies and self.feedback is not None and self.faults.feedback_lost(msg.seq):
                flags |= SAMPLE_FEEDBACK_LOST
                self.injected["feedback_losses"] += 1
                copies = 0
            for _ in range(copies):
                self.tap.sent(keys.STATE, send_ns, payload)  # entering the path, as sent
                if self.feedback is None:
                    self._pub_state.put(payload)
                else:
                    held = round(self.faults.feedback_extra_s(msg.seq) * 1e9)
                    self.feedback.put(send_ns + held, payload)
        self.samples += 1
        s = c.state
        row = SampleRow(
            seq=msg.seq,
            sample_ns=sample_ns,
            wake_ns=wake_ns,
            send_ns=send_ns,
            x=s.x,
            y=s.y,
            theta=s.theta,
            v=s.v,
            omega=s.omega,
            tau1=s.tau1,
            tau2=s.tau2,
            cmd1=c.cmd1,
            cmd2=c.cmd2,
            flags=flags,
        )
        if log:
            self.hoplog.append("samples", row)
        return row

    def _put_state(self, payload: bytes) -> None:
        self._pub_state.put(payload)

    def publish_status(self, state: str = "running") -> None:
        counters = {
            "epoch_ns": self.epoch_ns,  # a restarted controller joins the run with it
            "states": self._state_seq,
            "commands": self.cmd_tracker.counts.received,
            "timeouts": self.timeouts,
            "rejections": self.rejections.total,
            "violations": int(
                self.core.extremes.violations_v
                + self.core.extremes.violations_omega
                + self.core.extremes.violations_tau1
                + self.core.extremes.violations_tau2
            ),
        }
        if self.can is not None:
            counters.update(self.can.status_counters())
        self.hoplog.counters(self.final_counters())
        msg = Status(
            self.robot_id,
            self._status_seq,
            time.monotonic_ns(),
            "plant",
            state,
            1 if self.timed_out else 0,
            counters,
        )
        self._status_seq += 1
        self._pub_status.put(encode(msg))

    # --- events of the real-time loop -----------------------------------------------------
    def _take_arrivals(self) -> None:
        """Queue every source's arrivals at their landing times: the receive time plus the
        injected delay (``[timing]``, a [faults] burst); a source that keeps order (frames on
        a bus) never has one overtake another."""
        for source in self.sources:
            last_apply = 0
            for arrival in source.arrivals():
                recv_ns = arrival.recv_ns
                apply_ns = recv_ns + self.injector.extra_ns() + self._burst_ns(recv_ns)
                if source.keeps_order:
                    apply_ns = last_apply = max(apply_ns, last_apply)
                self._order += 1
                self.pending.append(Pending(apply_ns, self._order, source, arrival))

    def _mono(self, t: float) -> float:
        """CLOCK_MONOTONIC seconds of plant time ``t`` (the drives' clock)."""
        return self.epoch_ns / 1e9 + t

    def _burst_ns(self, recv_ns: int) -> int:
        """Extra delay of a [faults] delay burst for a command arriving at ``recv_ns``."""
        extra = self.faults.delay_extra_s((recv_ns - self.epoch_ns) / 1e9)
        if extra > 0.0:
            self.injected["delay_bursts"] += 1
        return int(extra * 1e9)

    def _outcome(self, p: Pending) -> ApplyOutcome:
        """apply.outcome of a landing: delayed by a [faults] burst, or on time."""
        burst = self.faults.delay_extra_s((p.recv_ns - self.epoch_ns) / 1e9) > 0.0
        return ApplyOutcome.BURST if burst else ApplyOutcome.LANDED

    def _apply(self, p: Pending) -> None:
        """Land one pending command at its time (the plant was advanced to it)."""
        apply_ns = max(p.apply_ns, self.epoch_ns + int(self.core.t * 1e9))
        got = p.source.land(p.arrival, apply_ns)
        if got.hold is not None:
            self.core.hold(*got.hold)
        if got.outcome is None:  # not a command (a lifecycle frame): no landing
            return
        outcome = self._outcome(p) if got.outcome is ApplyOutcome.LANDED else got.outcome
        row = ApplyRow(
            path=p.source.path,
            seq=p.arrival.seq,
            node=got.node,
            recv_ns=p.recv_ns,
            apply_ns=apply_ns,
            tau1=got.tau1,
            tau2=got.tau2,
            outcome=outcome,
        )
        self.hoplog.append("apply", row)
        if outcome is ApplyOutcome.OVERTAKEN:
            self.rejections.count("overtaken")  # a newer command already landed
            return
        if outcome is ApplyOutcome.REFUSED:
            # A drive's watchdog is fed by accepted commands only, and so is the command
            # timeout.
            return
        self._last_cmd_recv_ns = p.recv_ns
        self.timed_out = False

    def _process_until(self, until_ns: int) -> None:
        """Land every pending command due by ``until_ns`` and the command timeout, in time
        order, advancing the plant lazily to each event."""
        self._take_arrivals()
        self.pending.sort()
        while True:
            due = self.pending[0] if self.pending and self.pending[0].apply_ns <= until_ns else None
            timeout_ns = (
                self._last_cmd_recv_ns + self.command_timeout_ns
                if self._last_cmd_recv_ns is not None and not self.timed_out
                else None
            )
            if (
                timeout_ns is not None
                and timeout_ns <= until_ns
                and (due is None or timeout_ns < due.apply_ns)
            ):
                self.core.advance_to(max(self.core.t, self._t(timeout_ns)))
                self.core.hold(0.0, 0.0)
                if self.applied is not None:
                    self.applied.zero(timeout_ns)
                self.timed_out = True
                self.timeouts += 1
                self.hoplog.append(
                    "zero", ZeroRow(timeout_ns=timeout_ns, applied_ns=time.monotonic_ns())
                )
                continue
            if due is None:
                break
            self.pending.pop(0)
            self.core.advance_to(max(self.core.t, self._t(due.apply_ns)))
            self._apply(due)
        self.core.advance_to(max(self.core.t, self._t(until_ns)))

    def _read_sources(self, now: float | None = None) -> None:
        """Every source's receiver at the plant's time (the drives' feedback and one
        controller step); the plant then holds what the applied one has in force. ``now``:
        the receivers' clock (default: the monotonic time of the plant's time)."""
        c = self.core
        at = self._mono(c.t) if now is None else now
        for source in self.sources:
            torques = source.in_force(at, c.t, c.state)
            if source is self.applied and torques is not None and torques != (c.cmd1, c.cmd2):
                c.hold(*torques)

    # --- real time -----------------------------------------------------------------------
    def run_realtime(self, stop: Any, end_ns: int) -> None:
        # Slots count from the epoch; a plant restarted mid-run starts at the next one.
        first = max(0, -(-(time.monotonic_ns() - self.epoch_ns) // self.sensor_period_ns))
        clock = DeadlineClock(self.sensor_period_ns, self.epoch_ns, first_k=first)
        self.clock = clock
        next_status = time.monotonic_ns()
        lead = min(INTEGRATE_AFTER_SAMPLE_NS, self.sensor_period_ns // 2)
        while not stop:
            early = clock.due_ns() - lead
            if time.monotonic_ns() < early:
                # Most of the period is integrated before the sample: every command landing
                # by `early` has arrived, so the plant is the same, and the State leaves the
                # sample time with only the last `lead` of dynamics still to integrate.
                sleep_until_ns(early)
                self._process_until(early)
                # The quiet point of the period: the last command landed, the State not due.
                self.tap.flush_if_due(early)
            tick = clock.next()
            if tick.deadline_ns > end_ns:
                break
            self._process_until(tick.deadline_ns)
            self._publish_state(tick.deadline_ns, tick.k, tick.wake_ns)
            self._read_sources()
            if tick.wake_ns >= next_status:
                next_status = tick.wake_ns + 200_000_000
                self.publish_status()
                self.tap.flush_if_late(tick.wake_ns)  # a plant too late for its quiet point
        self.tap.close()
        self.publish_status("stopped")

    # --- lockstep --------------------------------------------------------------------------
    def run_lockstep(self, stop: Any, n_periods: int, offsets: list[int], wait_s: float = 10.0):
        """State k at t_k = k Ts; wait for the command computed from it; it lands ``offsets[k]``
        plant steps after t_k (delay + jitter rounded to the step, as the simulator draws
        them); the newest by sequence number wins, older ones are dropped. Each period is
        :meth:`PlantCore.lockstep_period`, the sampled-data step of
        :func:`hil.sim.core.simulate`."""
        c = self.core
        h = c.h
        m = max(1, round(self.ts / h))
        landed: list[tuple[Command, bool]] = []
        hold = Hold(log=landed)
        hold.cmd1, hold.cmd2 = c.cmd1, c.cmd2
        for k in range(n_periods):
            if stop:
                break
            c.t = k * m * h
            got = self._exchange(k, self.epoch_ns + round(k * self.ts * 1e9), wait_s, stop)
            if got is None:
                break
            msg, recv_ns, row = got
            note = (recv_ns, msg.tau1, msg.tau2)
            tau1, tau2 = c.lockstep_period(hold, k, m, offsets[k], msg.tau1, msg.tau2, note)
            # Hop-log order: landings at t_k, State k's row, then the landings within the
            # period. The row's applied torque is what acts from t_k on (as in the simulator's
            # trace).
            at_tk = [e for e in landed if e[0].land == k * m]
            self._log_landings(at_tk, h)
            self.hoplog.append("samples", row._replace(tau1=tau1, tau2=tau2))
            self._log_landings(landed[len(at_tk) :], h)
            landed.clear()
            self.tap.flush_if_due(time.monotonic_ns())
        self.tap.close()
        self.publish_status("stopped")

    def _log_landings(self, landed: list[tuple[Command, bool]], h: float) -> None:
        """Hop-log lockstep landings (an overtaken command is refused)."""
        for cmd, taken in landed:
            recv_ns, tau1, tau2 = cmd.note
            # Virtual time: the landing is ``cmd.land`` plant steps after the epoch.
            land_ns = self.epoch_ns + round(cmd.land * h * 1e9)
            row = ApplyRow(
                path=CmdPath.ZENOH,
                seq=cmd.seq,
                node=NO_NODE,
                recv_ns=recv_ns,
                apply_ns=land_ns,
                tau1=tau1,
                tau2=tau2,
                outcome=ApplyOutcome.LANDED if taken else ApplyOutcome.OVERTAKEN,
            )
            self.hoplog.append("apply", row)
            if not taken:
                self.rejections.count("overtaken")

    def _exchange(
        self, k: int, sample_ns: int, wait_s: float, stop: Any
    ) -> tuple[TorqueCommand, int, SampleRow] | None:
        """Publish State k and wait for the command computed from it (re-sending the state
        if a message was lost); returns (command, its receive time, State k's log row)."""
        deadline = time.monotonic() + wait_s
        while not stop and time.monotonic() < deadline:
            if self._state_seq > k:  # a re-send: one trace row per sample
                self.resends += 1
                self.samples -= 1
            self._state_seq = k
            row = self._publish_state(sample_ns, k, time.monotonic_ns(), log=False)
            got = self.zenoh.reply_to(k, time.monotonic() + 0.5, stop)
            if got is not None:
                return *got, row
        return None

    def continue_after(self, previous: Any) -> None:
        """A restart: the crashed predecessor's epoch, sample numbering and robot (its last
        logged sample; it coasts with zero torque until the next command lands)."""
        from plant_emulator.dynamics import PlantState

        self.epoch_ns = int(previous.meta["epoch_ns"])
        rows = previous.rows.get("samples", [])
        if rows:
            last = previous.table("samples")[-1]
            # States sent but not yet logged when the predecessor died (its last chunk): skip a
            # second's worth of numbers so none is reused.
            self._state_seq = int(last["seq"]) + 1 + math.ceil(1e9 / self.sensor_period_ns)
            self.core.state = PlantState(
                last["x"], last["y"], last["theta"], last["v"], last["omega"], 0.0, 0.0
            )
            self.core.t = (int(last["sample_ns"]) - self.epoch_ns) / 1e9
        self.restarted = True

    def final_counters(self) -> dict[str, Any]:
        """The service's counters (the hop log's footer, and its periodic snapshots)."""
        e = self.core.extremes
        return {
            "extremes": {
                "max_abs_v": e.max_abs_v,
                "max_abs_omega": e.max_abs_omega,
                "max_abs_tau1": e.max_abs_tau1,
                "max_abs_tau2": e.max_abs_tau2,
                "violations": {
                    "v": int(e.violations_v),
                    "omega": int(e.violations_omega),
                    "tau1": int(e.violations_tau1),
                    "tau2": int(e.violations_tau2),
                },
                "steps": e.steps,
                "nonfinite_steps": int(e.nonfinite_steps),
                "nonfinite_first_t_s": e.nonfinite_first_t_s(),
            },
            "final": list(self.core.state),
            "final_t": self.core.t,
            "samples": self.samples,
            "cmd_counts": self.cmd_tracker.counts.as_dict(),
            "rejections": self.rejections.snapshot(),
            "timeouts": self.timeouts,
            "lockstep_resends": self.resends,
            "restarted": getattr(self, "restarted", False),
            "injected": {
                **self.injected,
                "can_frame_losses": self.can.injected_frame_losses if self.can else 0,
                "encoder_feedback_losses": self.can.feedback_losses if self.can else 0,
            },
            "deadline_misses": self.clock.misses if self.clock else 0,
            "skipped_slots": self.clock.skipped if self.clock else 0,
            "tap": self.tap.counters(),
            "can": None if self.can is None else self.can.counters(),
        }


def build_plant(s: RunSettings, at_rest: bool = False) -> tuple[PlantCore, Sensor]:
    """(the core, the sensor) for the run ``s`` from its settings alone (``at_rest``: the
    initial pose with v = omega = 0, as the free-running drives start)."""
    from plant_emulator.dynamics import track_initial
    from plant_emulator.from_settings import drag_of, initial_state, sensor_of

    limits = s.limits_value
    core = PlantCore(
        initial_state(s, at_rest),
        h=s.plant_step,
        limits=limits,
        disturbance=Disturbance(**s.disturbance),
        lag=s.lag,
        seed=None,
        drag=drag_of(s),
        extremes=Extremes(),
    )
    track_initial(core.extremes, core.state, limits)
    return core, sensor_of(s)


def _open_drives(
    s: RunSettings, core: PlantCore, hoplog: HopLogWriter, faults: Faults, stack: Any
) -> CanCommands | None:
    """The virtual ODrives on the run's CAN bus as a command source (None when the run has no
    CAN bus); their bus is closed by ``stack``."""
    bus = s.open_can_bus()
    if bus is None:
        return None
    from plant_emulator.drive_plant import run_drive_config
    from plant_emulator.odrive import VirtualDrivePair
    from protocol.can.wheel_mapping import RobotGeometry

    cs = s.can_settings()
    geom = RobotGeometry(**s.robot)
    # The firmware's defaults with what the run's settings set (the applied (tau1, tau2) is
    # clamped to (2) after decoding, whatever the drives let through).
    pair = VirtualDrivePair(cs.node_right, cs.node_left, config=run_drive_config(s))
    drive_plant = DrivePlant(pair, geom, core.limits, core.t, core.state, time.monotonic())
    can = CanDrives(bus, pair, hoplog, immediate=True, faults=faults)
    stack.callback(can.close)  # closes the bus: registered before anything can fail
    can.start()
    return CanCommands(can, drive_plant)


def main_from_settings(settings_path: str, *more: str) -> int:
    """Entry of ``python -m plant_emulator SETTINGS.json [MORE.json ...]`` (``hil`` resolved
    the run into that file: :class:`protocol.settings.RunSettings`); several files: one
    process emulates each of those robots (:func:`main_group`)."""
    from runtime.signals import stop_on_signals
    from runtime.zsession import check_credentials, open_session

    if more:
        return main_group([settings_path, *more])
    s = RunSettings.load(settings_path)
    s.validate()
    check_credentials(s.zenoh_endpoint, s.zenoh_mode)  # a bad credentials file: exit before a log
    with contextlib.ExitStack() as stack:
        # Signals first: a Ctrl-C during the set-up (Zenoh, CAN) must stop the start gate too.
        stop = stack.enter_context(stop_on_signals())
        session = open_session(s.zenoh_endpoint, mode=s.zenoh_mode)
        stack.callback(session.close)
        svc, hoplog = build_service(s, session, stack)
        return _serve(svc, s, stop, hoplog, stack)


def main_group(paths: list[str]) -> int:
    """Several robots' plants in one process (a fleet on few cores: runtime.group): each its
    own :class:`PlantService` (its keys, state, hop log in its own run folder, deadlines on
    its own epoch) in its own thread; the session, the scheduling and the signals shared."""
    from runtime.group import load_group, run_threads
    from runtime.realtime import restore_gc
    from runtime.signals import stop_on_signals
    from runtime.zsession import open_session

    settings = load_group(paths)
    first = settings[0]
    with contextlib.ExitStack() as stack:
        stop = stack.enter_context(stop_on_signals())
        session = open_session(first.zenoh_endpoint, mode=first.zenoh_mode)
        stack.callback(session.close)
        built = [build_service(s, session, stack) for s in settings]
        # Once, before the threads (they inherit the policy and the CPU).
        sched = setup_scheduling(
            first.scheduling, cpu=first.cpu_plant, freeze_gc=True, idle=first.idle
        )
        stack.callback(restore_gc)
        bodies = [
            lambda svc=svc, s=s, log=log: _serve(svc, s, stop, log, stack, sched)
            for (svc, log), s in zip(built, settings, strict=True)
        ]
        return run_threads([s.robot_id for s in settings], bodies)


def build_service(s: RunSettings, session: Any, stack: Any) -> tuple[PlantService, HopLogWriter]:
    """One robot's plant service and its hop log on ``session``; what it opened is closed
    by ``stack``."""
    from runtime.clocksync import ClockEcho

    core, sensor = build_plant(s)
    sensor_ts = s.ts if s.lockstep else s.sensor_ts
    faults = Faults.of(s.faults)
    log_path = Path(s.out_dir) / PLANT_HOPLOG
    # A predecessor that crashed mid-run left its log open: this is a restart, which continues
    # that log and the emulated robot from its last logged sample (motors unpowered meanwhile).
    previous = crashed_log(log_path)
    hoplog = HopLogWriter(
        log_path,
        "plant",
        PLANT_TABLES,
        {
            "robot_id": s.robot_id,
            "sensor_period_ns": period_ns(sensor_ts),
            "control_period_ns": period_ns(s.ts),
            "plant_step_ns": round(core.h * 1e9),
            "lockstep": s.lockstep,
            "cmd_path": s.cmd_path,
            "command_timeout_s": s.command_timeout,
            "delay_s": s.delay,
            "jitter_s": s.jitter,
            "jitter_kind": s.jitter_kind,
            "faults": asdict(faults),
            "epoch_ns": s.epoch_ns,
        },
        append=previous is not None,
    )
    box: list[PlantService] = []
    stack.callback(lambda: hoplog.close(box[0].final_counters() if box else None))
    stack.callback(ClockEcho(session, s.robot_id).close)  # others' offsets to this clock
    can = _open_drives(s, core, hoplog, faults, stack)
    svc = PlantService(
        core,
        sensor,
        session,
        s.robot_id,
        s.epoch_ns,
        s.ts,
        sensor_ts,
        cmd_path=s.cmd_path,
        command_timeout=s.command_timeout,
        injector=DelayInjector(s.delay, s.jitter, s.jitter_kind, s.seed),
        can=can,
        hoplog=hoplog,
        faults=faults,
    )
    box.append(svc)
    if svc.feedback is not None:
        stack.callback(svc.feedback.close)
    if previous is not None:
        svc.continue_after(previous)
    return svc, hoplog


def _serve(
    svc: PlantService,
    s: RunSettings,
    stop: Any,
    hoplog: HopLogWriter,
    stack: Any,
    sched: Any = None,
) -> int:
    """The start gate (unless the epoch is given), then the run; returns the exit code.
    ``sched``: the process' scheduling, already set up (a group of robots); else set up
    here."""
    from runtime.realtime import restore_gc
    from runtime.startgate import StartGate

    can = svc.can
    gate = StartGate(svc.session, s.robot_id, "plant")
    # Scheduling first, readiness after: the set-up (mlockall, a full collection, the GC
    # frozen) must be done before t = 0, or the first samples start late.
    if sched is None:
        sched = setup_scheduling(s.scheduling, cpu=s.cpu_plant, freeze_gc=True, idle=s.idle)
        stack.callback(restore_gc)
    hoplog.update_meta({"scheduling": sched.as_dict()})
    if svc.epoch_ns == 0:

        def idle() -> None:
            # The edge answers the lifecycle and sends the cyclic frames by itself; keep the
            # drives' feedback (the robot at its initial state) and watchdog current.
            for source in svc.sources:
                source.in_force(time.monotonic(), svc.core.t, svc.core.state)

        got = gate.wait(stop, timeout=s.start_timeout, idle=idle)
        if got is None:
            # Stopped (a signal: the stop asked for, as mid-run: exit 0), or the start message
            # never came (exit 1).
            why = "stopped" if stop else f"no start message within {s.start_timeout:g} s"
            print(f"no start: {why}", flush=True)
            return 0 if stop else 1
        svc.epoch_ns = got
    hoplog.update_meta({"epoch_ns": svc.epoch_ns})
    if can is not None:
        # From t = 0 the applied CAN path lands each frame at its time in the plant's loop;
        # until then (the start is announced up to a few hundred ms ahead) the controller's
        # arming acts at once, or the drives would arm only at t = 0 and report it in their
        # next heartbeat, up to 100 ms into the run: samples without a command, D raised.
        can.immediate_until_ns = svc.epoch_ns
        can.immediate = svc.applied_path != CmdPath.CAN
    print(f"running epoch_ns={svc.epoch_ns} scheduling={sched.policy}", flush=True)
    if s.lockstep:
        from plant_emulator.from_settings import lockstep_offsets

        n = max(1, round(s.duration / s.ts))
        svc.run_lockstep(stop, n, lockstep_offsets(s, n, svc.core.h))
    else:
        end_ns = svc.epoch_ns + int(s.duration * 1e9)
        svc.run_realtime(stop, end_ns)
    return 0

"""The plant's command sources: where commands come from, behind one interface.

:class:`plant_emulator.service.PlantService` orders events in time (sensor ticks, landings, the
command timeout) and applies them; where a command came from and what landing it does to the
receiver is a :class:`CommandSource`'s business (ros2_control's read/write split):

- ``arrivals()``: the commands received since the last call that the plant is to land, each an
  :class:`Arrival` stamped with its receive time, in arrival order. A source on the shadow path
  (the run applies the other one) returns none: every arrival is in the hop log's ``cmd_rx``
  already, and the CAN source hands its frames to the drives at once.
- ``land(arrival, apply_ns)``: apply one at its landing time; the :class:`Landing` says what the
  plant holds from then on and what the hop log's ``apply`` row says.
- ``zero(at_ns)``: the command timeout fired (the drives' inputs are zeroed).
- ``in_force(now, t, state)``: the torque the receiver holds at plant time ``t`` (the drives'
  loops and watchdog run), or None for a receiver that holds what it was last given.

Two sources: :class:`ZenohCommands` (the TorqueCommand subscriber) and :class:`CanCommands`
(Set_Input_Torque frames through the virtual drives of :mod:`plant_emulator.can_drives`).
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Any, NamedTuple, Protocol

from plant_emulator.can_drives import CanDrives
from plant_emulator.drive_plant import DrivePlant
from protocol import keys
from protocol.can.codec import Frame, ODriveError
from protocol.hoplog import (
    NO_NODE,
    ApplyOutcome,
    CmdPath,
    CmdRxRow,
    HopLogWriter,
    RxVerdict,
)
from protocol.messages import FLAG_STOP, TorqueCommand, decode_counted
from protocol.rejections import RejectionCounter
from protocol.sequence import SequenceTracker
from runtime.tap import Tap


class Arrival(NamedTuple):
    """A command as it arrived, before it lands: a TorqueCommand (Zenoh) or a frame (CAN)."""

    recv_ns: int
    seq: int  # the command's seq; a CAN frame's index among its node's torque frames, or NO_SEQ
    command: TorqueCommand | None = None
    frame: Frame | None = None


class Landing(NamedTuple):
    """What landing one arrival did: the torques the plant holds from now (None: unchanged),
    and the ``apply`` row's outcome (None: not a command, e.g. a lifecycle frame: no row),
    node and torques."""

    hold: tuple[float, float] | None
    outcome: ApplyOutcome | None
    node: int = NO_NODE
    tau1: float = 0.0
    tau2: float = 0.0


class CommandSource(Protocol):
    """Where commands come from (see the module docstring)."""

    path: CmdPath
    keeps_order: bool  # landings keep the arrival order (frames on one bus)
    applied: bool  # the run lands this source's commands (set by the service)

    def arrivals(self) -> list[Arrival]: ...

    def land(self, arrival: Arrival, apply_ns: int) -> Landing: ...

    def zero(self, at_ns: int) -> None: ...

    def in_force(self, now: float, t: float, state: Any) -> tuple[float, float] | None: ...


class ZenohCommands:
    """TorqueCommand on Zenoh: every arrival logged (``cmd_rx``); on the applied path the fresh
    ones (by sequence number) land, unless computed from a sample older than the command
    timeout; a command older than one already landed is overtaken."""

    path = CmdPath.ZENOH
    keeps_order = False

    def __init__(
        self,
        session: Any,
        robot_id: str,
        hoplog: HopLogWriter,
        rejections: RejectionCounter,
        tracker: SequenceTracker,
        stale_after_ns: int,
        tap: Tap | None = None,
    ) -> None:
        from runtime.zsession import payload_bytes

        self.robot_id = robot_id
        self.tap = tap
        self.hoplog = hoplog
        self.rejections = rejections
        self.tracker = tracker
        self.stale_after_ns = stale_after_ns
        self.applied = False
        self._payload = payload_bytes
        self._inbox: collections.deque[tuple[int, TorqueCommand]] = collections.deque()
        self._cond = threading.Condition()
        self._last_landed_seq = -1
        self._sub = session.declare_subscriber(keys.torque_key(robot_id), self._on_cmd)

    def _refused(self, recv_ns: int, payload: bytes, reason: str) -> None:
        if self.tap is not None:
            self.tap.rejected(keys.TORQUE, recv_ns, payload, reason)

    def _on_cmd(self, sample: Any) -> None:
        recv_ns = time.monotonic_ns()
        payload = self._payload(sample)
        msg = decode_counted(
            payload,
            self.rejections,
            TorqueCommand,
            lambda why: self._refused(recv_ns, payload, why),
        )
        if msg is None:
            return
        if msg.robot_id != self.robot_id:
            self.rejections.count("wrong_robot")
            self._refused(recv_ns, payload, "wrong_robot")
            return
        row = CmdRxRow(
            path=CmdPath.ZENOH,
            seq=msg.seq,
            state_seq=msg.state_seq,
            state_sample_ns=msg.state_sample_time_ns,
            compute_start_ns=msg.compute_start_ns,
            send_ns=msg.send_time_ns,
            recv_ns=recv_ns,
            tau1=msg.tau1,
            tau2=msg.tau2,
            node=NO_NODE,
            verdict=RxVerdict.ACCEPTED,
        )
        self.hoplog.append("cmd_rx", row)
        with self._cond:
            self._inbox.append((recv_ns, msg))
            self._cond.notify_all()

    def arrivals(self) -> list[Arrival]:
        out: list[Arrival] = []
        inbox = self._inbox
        while inbox:
            recv_ns, msg = inbox.popleft()
            if not self.applied or not self.tracker.observe(msg.seq).fresh:
                continue
            if recv_ns - msg.state_sample_time_ns > self.stale_after_ns:
                # Computed from a sample older than the command timeout (a link that came back
                # with old messages): a drive would have zeroed already; refuse it.
                self.rejections.count("stale_command")
                continue
            out.append(Arrival(recv_ns, msg.seq, command=msg))
        return out

    def land(self, arrival: Arrival, apply_ns: int) -> Landing:
        msg = arrival.command
        assert msg is not None
        if msg.seq < self._last_landed_seq:  # a newer command already landed
            return Landing(None, ApplyOutcome.OVERTAKEN, tau1=msg.tau1, tau2=msg.tau2)
        self._last_landed_seq = msg.seq
        return Landing(
            (msg.tau1, msg.tau2),
            ApplyOutcome.LANDED,
            tau1=msg.tau1,
            tau2=msg.tau2,
        )

    def zero(self, at_ns: int) -> None:
        """Nothing to do: the plant holds zero torque itself."""

    def in_force(self, now: float, t: float, state: Any) -> None:
        return None

    def reply_to(self, k: int, until: float, stop: Any) -> tuple[TorqueCommand, int] | None:
        """Lockstep: wait until ``until`` (monotonic s) for the command computed from State k;
        returns (it, its receive time), or None. Other commands are dropped."""
        with self._cond:
            while time.monotonic() < until and not stop:
                while self._inbox:
                    recv_ns, msg = self._inbox.popleft()
                    if msg.state_seq == k and not (msg.flags & FLAG_STOP):
                        self.tracker.observe(msg.seq)
                        return msg, recv_ns
                self._cond.wait(timeout=0.05)
        return None


class CanCommands:
    """Host frames through the virtual drives (:class:`plant_emulator.can_drives.CanDrives`
    logs their arrivals). On the applied path every frame the edge queued lands at its time
    (bus order kept) and the plant holds what the drives apply; on the shadow path the edge's
    frames go to the drives as they arrive."""

    path = CmdPath.CAN
    keeps_order = True

    def __init__(self, drives: CanDrives, drive_plant: DrivePlant) -> None:
        self.drives = drives
        self.drive_plant = drive_plant
        self._drive_fault_done = False  # [faults] drive_fault_at fires once
        self.applied = False

    def arrivals(self) -> list[Arrival]:
        out: list[Arrival] = []
        edge = self.drives
        inbox = edge.inbox
        while inbox:
            recv_ns, frame, index = inbox.popleft()
            if self.applied:
                out.append(Arrival(recv_ns, index, frame=frame))
            else:
                with edge.lock:
                    answers = edge.pair.receive(recv_ns / 1e9, frame)
                edge.send(answers)
        return out

    def land(self, arrival: Arrival, apply_ns: int) -> Landing:
        frame = arrival.frame
        assert frame is not None
        edge = self.drives
        node = edge.torque_input_node(frame)
        with edge.lock:
            answers = edge.pair.receive(apply_ns / 1e9, frame)
            fed = edge.pair.last_fed
            t1, t2 = self.drive_plant.torques()
        if answers:
            edge.send(answers)
        if node is None:  # a lifecycle frame, or none of these drives'
            return Landing((t1, t2), None)
        # Refused by the drive (non-finite, short, disarmed...): the torque in force stays.
        outcome = ApplyOutcome.LANDED if fed else ApplyOutcome.REFUSED
        return Landing((t1, t2), outcome, node, t1, t2)

    def zero(self, at_ns: int) -> None:
        with self.drives.lock:
            self.drives.pair.zero_inputs(at_ns / 1e9)

    def in_force(self, now: float, t: float, state: Any) -> tuple[float, float]:
        """The drives' feedback at plant time ``t`` and one controller step (watchdog,
        loops); the torques they apply then."""
        with self.drives.lock:
            self._inject_drive_fault(now, t)
            self.drive_plant.update(now, t, state)
            return self.drive_plant.torques()

    def _inject_drive_fault(self, now: float, t: float) -> None:
        """[faults] drive_fault_at: once, at plant time t, the drive disarms with an
        over-speed error, as a real ODrive does when its velocity limit is exceeded."""
        f = self.drives.faults
        if f.drive_fault_at <= 0.0 or t < f.drive_fault_at or self._drive_fault_done:
            return
        self._drive_fault_done = True
        drive = self.drives.pair.drives.get(int(f.drive_fault_node))
        if drive is not None:
            drive.disarm(ODriveError.VELOCITY_LIMIT_VIOLATION, "injected_overspeed", now)

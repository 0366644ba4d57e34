"""The controller's command paths: how a computed command leaves for the plant.

The service computes one :class:`protocol.messages.TorqueCommand` per tick and hands it to each
of its paths (:class:`CommandPath`), which say when it left: :class:`ZenohCommandPath` (the
message on Zenoh, through the [faults] drop, duplicate and reorder injections) and
:class:`CanCommandPath` (Set_Input_Torque frames to the drives, after their lifecycle, on the
host's one CAN edge, :class:`protocol.can.drive_link.DriveLink`). Which path the plant applies
is the plant's business; the controller sends on every path it has.
"""

from __future__ import annotations

import contextlib
import math
import struct
import threading
import time
from typing import Any, NamedTuple, Protocol

from protocol import keys
from protocol.can.codec import Cmd, Frame, split_id
from protocol.can.drive_link import DriveLink, from_message, to_message
from protocol.can.drive_profile import Phase
from protocol.can.wheel_mapping import motor_torques
from protocol.faults import Faults, every_nth
from protocol.hoplog import (
    NO_SEQ,
    NO_STAMP,
    TICK_DROPPED,
    TICK_DUPLICATED,
    TICK_REORDERED,
    CanTxRow,
    CmdPath,
    HopLogWriter,
)
from protocol.messages import FLAG_STOP, TorqueCommand, encode
from runtime.tap import Tap


class Sent(NamedTuple):
    """One command on one path: when it left (``NO_STAMP``: it did not, e.g. drives not armed)
    and the tick flags of the [faults] injections it met."""

    send_ns: int
    flags: int = 0


NOT_SENT = Sent(NO_STAMP)


class CommandPath(Protocol):
    """One way the controller's commands reach the plant."""

    path: CmdPath

    def send(self, cmd: TorqueCommand) -> Sent:
        """Send ``cmd`` now (called by the control loop: cheap, no waiting)."""
        ...


class ZenohCommandPath:
    """TorqueCommand on Zenoh, through the [faults] injections (:mod:`protocol.faults`); its
    send time is the message's own ``send_time_ns``."""

    path = CmdPath.ZENOH

    def __init__(
        self, session: Any, robot_id: str, faults: Faults | None = None, tap: Tap | None = None
    ) -> None:
        from runtime.zsession import publisher

        self._publisher = publisher(session, keys.torque_key(robot_id))
        self._tap = tap
        self.faults = faults or Faults()
        self.injected = {"drops": 0, "duplicates": 0, "reorders": 0}
        self.epoch_ns = 0  # set at the start: drop bursts are placed in run time
        self._held: bytes | None = None  # a command a [faults] reorder publishes after the next
        self._last: bytes | None = None

    def _pub_put(self, payload: bytes) -> None:
        """One command on the wire, and in the service's tap."""
        self._publisher.put(payload)
        if self._tap is not None:
            self._tap.sent(keys.TORQUE, time.monotonic_ns(), payload)

    def matched(self) -> bool:
        """Whether a subscriber of the command key (the plant) is reachable now: the route
        exists, so the first command is not lost to one still forming (True where the
        Zenoh build cannot tell)."""
        try:
            return bool(self._publisher.matching_status.matching)
        except Exception:  # an older zenoh without matching status: nothing to wait for
            return True

    def send(self, cmd: TorqueCommand) -> Sent:
        self._last = encode(cmd)
        return Sent(cmd.send_time_ns, self._put(self._last, cmd.seq, cmd.flags, cmd.send_time_ns))

    def resend_last(self) -> bool:
        """Publish the last command again, unchanged (lockstep: the plant re-sent the state
        because the command was lost); False when there is none."""
        if not self._last:
            return False
        self._pub_put(self._last)
        return True

    def _put(self, payload: bytes, seq: int, flags: int, send_ns: int = 0) -> int:
        """Put one command through the [faults] injections; returns the tick's fault flags."""
        f = self.faults
        held, self._held = self._held, None
        out_flags = 0
        t_s = (send_ns - self.epoch_ns) / 1e9 if self.epoch_ns > 0 else -1.0
        if flags & FLAG_STOP:
            pass
        elif f.command_dropped(seq, t_s):
            self.injected["drops"] += 1
            if held is not None:
                self._pub_put(held)
            return TICK_DROPPED
        elif every_nth(seq, f.command_reorder_every) and held is None:
            self._held = payload  # published after the next command
            self.injected["reorders"] += 1
            return TICK_REORDERED
        self._pub_put(payload)
        if held is not None:
            self._pub_put(held)
        if not (flags & FLAG_STOP) and every_nth(seq, f.command_duplicate_every):
            self._pub_put(payload)
            self.injected["duplicates"] += 1
            out_flags |= TICK_DUPLICATED
        return out_flags


class CanCommandPath(DriveLink):
    """The controller's CAN edge: HostLifecycle for both drives, torques as Set_Input_Torque.

    A reader thread feeds heartbeats to the lifecycle (under a lock) and ticks it; the control
    loop only encodes and sends the two torque frames, stamping each send per node so the
    plant's arrivals can be matched to this send log in per-node order. A
    :class:`controller_service.command_paths.CommandPath`.
    """

    path = CmdPath.CAN

    def __init__(
        self,
        bus: Any,
        lifecycle: Any,
        geometry: Any,
        hoplog: HopLogWriter,
        faults: Faults | None = None,
    ) -> None:
        super().__init__(bus, lifecycle)
        self.geometry = geometry
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._pending_arm = False
        self._stop = threading.Event()
        self.sent_frames = 0
        self.send_errors = 0
        self.arm_sends = 0  # lifecycle sequences sent: each holds one zero torque per node
        self.rearms = 0
        self.hoplog = hoplog
        self.faults = faults or Faults()
        self.epoch_ns = 0  # set at the start: bus-off bursts are placed in run time
        self.injected_bus_off = 0
        self._thread = threading.Thread(target=self._reader, name="can-reader", daemon=True)

    def start(self) -> None:
        """Arm the drives once both are heard (their heartbeats): frames sent before a drive
        listens would be lost, and on a bus that names no frame (socketcan) a lost frame
        shifts the matching of every later one."""
        self._pending_arm = True
        self._thread.start()

    def send_frames(self, frames: list[Frame], cmd_seq: int = NO_SEQ) -> int:
        """Send frames; every Set_Input_Torque is logged per node with the command it carries
        (NO_SEQ: a lifecycle zero), so arrivals can be matched in per-node order."""
        stamp = 0
        now = time.monotonic_ns()
        bus_off = self.epoch_ns > 0 and self.faults.bus_off((now - self.epoch_ns) / 1e9)
        # One sender at a time (the control loop and the lifecycle's reader thread both send):
        # the log's order is then the bus's, which the matching of arrivals relies on.
        with self._send_lock:
            for f in frames:
                node, cmd = split_id(f.arbitration_id)
                sent = end = NO_STAMP
                if bus_off:
                    self.injected_bus_off += 1  # a [faults] bus-off burst: the send fails
                else:
                    try:
                        # Stamped when handed to the bus, as a TorqueCommand is stamped before
                        # its put: a hop is then never negative.
                        handed = time.monotonic_ns()
                        self.bus.send(to_message(f), timeout=0.05)
                        sent = stamp = handed
                        end = int(getattr(self.bus, "last_end_ns", 0) or 0)
                        self.sent_frames += 1
                    except Exception:
                        self.send_errors += 1
                if cmd == Cmd.SET_INPUT_TORQUE:
                    value = struct.unpack_from("<f", f.data)[0] if len(f.data) >= 4 else math.nan
                    row = CanTxRow(
                        node=node, send_ns=sent, cmd_seq=cmd_seq, value=value, bus_end_ns=end
                    )
                    self.hoplog.append("can_tx", row)
        return stamp

    def _reader(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.05)
            except Exception:
                if self._stop.is_set():
                    return
                continue
            now = time.monotonic()
            with self._lock:
                if msg is not None:
                    self.lifecycle.receive(now, from_message(msg))
                frames = self._lifecycle_frames(now)
            if frames:
                self.send_frames(frames)

    def _lifecycle_frames(self, now: float) -> list[Frame]:
        """What the lifecycle sends now (under the lock): the first arming once both drives
        are heard, its retries, and a counted re-arm after a drive faulted."""
        if self._pending_arm:
            if not all(d.heartbeats > 0 for d in self.lifecycle.drives.values()):
                return []
            self._pending_arm = False
            self.arm_sends += 1
            return self.lifecycle.start(now)
        frames = self.lifecycle.tick(now)
        if frames:
            self.arm_sends += 1  # a re-sent lifecycle (it carries a zero torque)
        elif self.lifecycle.fault_reason and not self._stop.is_set():
            # A drive faulted (e.g. heartbeats late on a stalled host): re-arm rather than stay
            # silent for the rest of the run; counted.
            frames = self.lifecycle.start(now)
            self.arm_sends += 1
            self.rearms += 1
        return frames

    @property
    def active(self) -> bool:
        return self.lifecycle.phase is Phase.ACTIVE

    def send(self, cmd: TorqueCommand) -> Sent:
        """The command's torques as Set_Input_Torque frames (no [faults] flags: bus-off bursts
        are counted by the path)."""
        return Sent(self.send_torques(cmd.tau1, cmd.tau2, cmd.seq))

    def send_torques(self, tau1: float, tau2: float, cmd_seq: int) -> int:
        """Send both wheel torques; returns the send time (NO_STAMP when the drives are not
        armed)."""
        q = motor_torques(self.geometry, tau1, tau2)
        with self._lock:
            frames = self.lifecycle.torque_frames(q.right, q.left)
        if not frames:
            return NO_STAMP
        return self.send_frames(frames, cmd_seq)

    def close(self) -> None:
        with self._lock:
            frames = self.lifecycle.stop()
        self.send_frames(frames)
        self._stop.set()
        self._thread.join(timeout=1.0)
        with contextlib.suppress(Exception):  # a bus already gone is fine on the way out
            self.bus.shutdown()

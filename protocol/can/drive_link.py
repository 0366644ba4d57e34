"""The host's edge to the two drives: a python-can bus driven by :class:`HostLifecycle`.

Thin shell: all decisions are in :mod:`protocol.can.drive_profile`; this module only moves
frames between the bus and the state machine. ``python -m protocol.can.drive_link`` arms both
drives, sends a constant torque for some cycles, disarms them and prints a JSON summary (used by
the two-process tests and handy against real ODrives).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import can

from protocol.can.bus_factory import add_bus_arguments
from protocol.can.codec import AxisState, Frame
from protocol.can.drive_profile import HostLifecycle, Phase


def to_message(frame: Frame) -> can.Message:
    return can.Message(
        arbitration_id=frame.arbitration_id,
        data=None if frame.is_remote else frame.data,
        is_remote_frame=frame.is_remote,
        is_extended_id=frame.is_extended,
        dlc=0 if frame.is_remote else len(frame.data),
    )


def from_message(msg: can.Message) -> Frame:
    return Frame(
        msg.arbitration_id,
        bytes(msg.data) if not msg.is_remote_frame else b"",
        bool(msg.is_remote_frame),
        bool(msg.is_extended_id or msg.is_error_frame or msg.is_fd),
    )


class DriveLink:
    """The host's one CAN edge: moves frames between ``bus`` and ``lifecycle`` on the wall
    clock (time.monotonic). The controller's CAN command path is one
    (:class:`controller_service.command_paths.CanCommandPath`), with a reader thread and a
    send log of its own."""

    def __init__(self, bus: can.BusABC, lifecycle: HostLifecycle) -> None:
        self.bus = bus
        self.lifecycle = lifecycle

    def send_frames(self, frames: list[Frame]) -> None:
        for frame in frames:
            self.bus.send(to_message(frame), timeout=0.1)

    def pump(self, budget: float = 0.0) -> None:
        """Take every frame that arrives within ``budget`` seconds, then tick the lifecycle."""
        deadline = time.monotonic() + budget
        while True:
            msg = self.bus.recv(timeout=max(0.0, deadline - time.monotonic()))
            if msg is None:
                break
            self.lifecycle.receive(time.monotonic(), from_message(msg))
        self.send_frames(self.lifecycle.tick(time.monotonic()))

    def arm(self, timeout: float) -> bool:
        """Run the lifecycle until both drives are in closed loop or ``timeout`` passes."""
        self.send_frames(self.lifecycle.start(time.monotonic()))
        deadline = time.monotonic() + timeout
        while self.lifecycle.phase is Phase.ARMING and time.monotonic() < deadline:
            self.pump(0.02)
        return self.lifecycle.phase is Phase.ACTIVE

    def command(self, q_right: float, q_left: float) -> None:
        self.send_frames(self.lifecycle.torque_frames(q_right, q_left))

    def disarm(self, estop: bool = False, confirm_timeout: float = 0.0) -> bool:
        """Zero torque and IDLE (or Estop); optionally wait for heartbeats confirming it."""
        self.send_frames(self.lifecycle.stop(estop))
        deadline = time.monotonic() + confirm_timeout
        while True:
            if all(v.axis_state == AxisState.IDLE for v in self.lifecycle.drives.values()):
                return True
            if time.monotonic() >= deadline:
                return False
            self.pump(0.02)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    add_bus_arguments(p)
    p.add_argument("--torque", type=float, default=0.1, help="motor torque, right +, left -")
    p.add_argument("--cycles", type=int, default=100)
    p.add_argument("--period", type=float, default=0.005)
    p.add_argument("--arm-timeout", type=float, default=20.0)
    a = p.parse_args(argv)

    from protocol.can.bus_factory import open_bus_from_args

    bus = open_bus_from_args(a)
    life = HostLifecycle(node_right=a.node_right, node_left=a.node_left)
    link = DriveLink(bus, life)
    result: dict = {"armed": False}
    try:
        result["armed"] = link.arm(a.arm_timeout)
        sent = 0
        if result["armed"]:
            for _ in range(a.cycles):
                link.command(a.torque, -a.torque)
                sent += 1
                link.pump(a.period)
        result["phase_after_commands"] = life.phase.value
        result["fault_reason"] = life.fault_reason
        result["torque_cycles"] = sent
        result["idle_confirmed"] = link.disarm(confirm_timeout=5.0)
        result["drives"] = {
            str(node): {
                "heartbeats": v.heartbeats,
                "estimates": v.estimates,
                "axis_state": int(v.axis_state),
                "axis_error": v.axis_error,
                "pos_rev": v.pos_rev,
                "vel_rev_s": v.vel_rev_s,
            }
            for node, v in life.drives.items()
        }
        result["rejections"] = life.rejections.snapshot()
    finally:
        bus.shutdown()
    json.dump(result, sys.stdout)
    sys.stdout.write("\n")
    return 0 if result["armed"] and result["idle_confirmed"] else 1


if __name__ == "__main__":
    sys.exit(main())

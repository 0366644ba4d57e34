"""A test device over CAN written against the PyPI ``odrive-can`` client (it shares no code
with the bench): it arms both virtual ODrives in torque control and runs a simple speed loop
on each wheel, as a robot computer's drive node would.

Modes (each a known answer for the bench's figures at its edge):
- default (``--hz 0``): a torque frame to a wheel for each encoder-estimate frame of it, the
  torque from that estimate (``--wait-ms W``: W ms after the frame arrived);
- ``--hz F --jitter-ms J``: torques at F Hz of its own, each send moved by a uniform draw in
  [-J, +J] ms around its slot, from the newest estimates;
- ``--stall-at T --stall-ms S``: once, T s after arming, nothing is sent for S ms;
- ``--rearm``: a drive whose heartbeat says it left closed loop is re-armed (Clear_Errors,
  then Set_Axis_State 8), as a robot's drive node recovers from an over-speed trip. Without
  it, the device keeps sending torques to the disarmed drive;
- ``--fifo``: the device runs SCHED_FIFO (a real-time device), so that its own response does
  not move with the host's load (as tests/devices/zenoh_device.py).

    python tests/devices/odrive_can_device.py --interface zenoh_can --channel hil0 \
        --endpoint tcp/127.0.0.1:PORT --node-left 0 --node-right 1
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import random
import threading
import time
from typing import Any

import can
from odrive_can import ODriveCAN

VEL_REF = 1.0  # turns/s of each wheel
GAIN = 0.05  # N·m per turn/s of error
TAU_MAX = 0.1  # N·m, inside the drives' limits


def open_bus(a: argparse.Namespace) -> can.BusABC:
    kw: dict[str, Any] = {"interface": a.interface, "channel": a.channel}
    if a.interface == "zenoh_can" and a.endpoint:
        kw["endpoint"] = a.endpoint
    return can.Bus(**kw)


class Device:
    def __init__(self, a: argparse.Namespace, drives: dict[int, ODriveCAN]) -> None:
        self.a = a
        self.drives = drives
        self.vel = dict.fromkeys(drives, 0.0)
        self.lock = threading.Lock()
        self.armed_at: float | None = None
        self.stalled = False
        self.rearmed: dict[int, float] = {}

    def torque(self, node: int) -> float:
        return max(-TAU_MAX, min(TAU_MAX, GAIN * (VEL_REF - self.vel[node])))

    def maybe_stall(self) -> None:
        a = self.a
        if a.stall_at < 0 or self.stalled or self.armed_at is None:
            return
        if time.monotonic() - self.armed_at >= a.stall_at:
            self.stalled = True
            time.sleep(a.stall_ms / 1e3)

    def on_frame(self, msg: can.Message) -> None:
        """Every frame of the bus (a raw python-can listener): heartbeats, encoder estimates."""
        node, cmd = msg.arbitration_id >> 5, msg.arbitration_id & 0x1F
        if cmd == 0x01 and len(msg.data) >= 5 and node in self.drives:
            self.on_heartbeat(node, msg.data[4])
            return
        if cmd != 0x09 or msg.is_remote_frame or len(msg.data) != 8 or node not in self.drives:
            return
        arrived = time.monotonic()
        if msg.timestamp:
            # Waited for from the frame's own arrival (the bus's stamp, wall clock), not from
            # when this one thread got to it: the other wheel's frame, which came at the same
            # time, is not made to wait twice.
            arrived -= max(0.0, time.time() - msg.timestamp)
        vel = float(memoryview(bytes(msg.data)).cast("f")[1])
        with self.lock:
            self.vel[node] = vel
            if self.a.hz or self.armed_at is None:
                return
            self.maybe_stall()
            while time.monotonic() - arrived < self.a.wait_ms / 1e3:
                # busy (a timed sleep's wake-up lateness would blur the known answer), yet
                # letting the bus's receiving thread take the GIL: else the other wheel's
                # frame would be stamped only after this wait, and wait twice
                time.sleep(0)
            self.drives[node].set_input_torque(self.torque(node))

    def on_heartbeat(self, node: int, axis_state: int) -> None:
        now = time.monotonic()
        if not self.a.rearm or self.armed_at is None or axis_state == 8:
            return
        if now - self.rearmed.get(node, 0.0) < 0.2:
            return  # one attempt per 200 ms: the next heartbeat shows whether it took
        self.rearmed[node] = now
        with self.lock:
            drv = self.drives[node]
            drv.clear_errors()
            drv.set_controller_mode("TORQUE_CONTROL", "PASSTHROUGH")
            drv.set_axis_state_no_wait("CLOSED_LOOP_CONTROL")

    def periodic(self, end: float) -> None:
        period = 1.0 / self.a.hz
        k0, k = time.monotonic(), 0
        while time.monotonic() < end:
            k += 1
            due = k0 + k * period + random.uniform(-self.a.jitter_ms, self.a.jitter_ms) / 1e3
            if time.monotonic() > due + period:
                continue  # a slot missed by a stall is skipped, not sent in a burst
            while time.monotonic() < due:
                pass
            with self.lock:
                self.maybe_stall()
                for node, drv in self.drives.items():
                    drv.set_input_torque(self.torque(node))


async def main_async(a: argparse.Namespace) -> None:
    drives = {a.node_left: ODriveCAN(a.node_left, open_bus(a))}
    drives[a.node_right] = ODriveCAN(a.node_right, open_bus(a))
    raw = open_bus(a)
    dev = Device(a, drives)
    notifier = can.Notifier(raw, [dev.on_frame])
    try:
        for d in drives.values():
            await asyncio.wait_for(d.start(), 30.0)
        for d in drives.values():
            d.clear_errors()
            d.set_controller_mode("TORQUE_CONTROL", "PASSTHROUGH")
            d.set_input_torque(0.0)
        for d in drives.values():
            d.set_axis_state_no_wait("CLOSED_LOOP_CONTROL")
        print("armed", flush=True)
        dev.armed_at = time.monotonic()
        end = time.monotonic() + a.duration
        if a.hz:
            await asyncio.to_thread(dev.periodic, end)
        else:
            await asyncio.sleep(a.duration)
    finally:
        notifier.stop()
        for d in drives.values():
            d.stop()
        raw.shutdown()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--interface", default="zenoh_can")
    ap.add_argument("--channel", default="hil0")
    ap.add_argument("--endpoint", default="")
    ap.add_argument("--node-left", type=int, default=0)
    ap.add_argument("--node-right", type=int, default=1)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--hz", type=float, default=0.0)
    ap.add_argument("--jitter-ms", type=float, default=0.0)
    ap.add_argument("--wait-ms", type=float, default=0.0)
    ap.add_argument("--stall-at", type=float, default=-1.0)
    ap.add_argument("--stall-ms", type=float, default=0.0)
    ap.add_argument("--rearm", action="store_true")
    ap.add_argument("--fifo", action="store_true", help="run SCHED_FIFO (every thread)")
    a = ap.parse_args()
    if a.fifo:  # before the bus and the loop: their threads inherit the policy
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main_async(a))


if __name__ == "__main__":
    main()

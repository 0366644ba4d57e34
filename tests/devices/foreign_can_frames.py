"""A test device over CAN that never arms a drive: it sends what a shared bus carries beside
the drives (another node's Set_Input_Torque, an extended frame whose low bits read as one) and
Set_Input_Torque to node 0 while it is idle. None of it is a command the drives act on.

    python tests/devices/foreign_can_frames.py --endpoint tcp/127.0.0.1:PORT --seconds 8
"""

from __future__ import annotations

import argparse
import struct
import time

import can

SET_INPUT_TORQUE = 0x0E
OTHER_NODE = 28
EXTENDED_ID = (10_005_910 << 5) | SET_INPUT_TORQUE  # node bits far beyond CANSimple's 6


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--endpoint", required=True)
    p.add_argument("--channel", default="hil0")
    p.add_argument("--seconds", type=float, default=8.0)
    a = p.parse_args()
    bus = can.Bus(interface="zenoh_can", channel=a.channel, endpoint=a.endpoint)
    torque = struct.pack("<f", 0.05)
    frames = [
        can.Message(arbitration_id=(0 << 5) | SET_INPUT_TORQUE, data=torque, is_extended_id=False),
        can.Message(
            arbitration_id=(OTHER_NODE << 5) | SET_INPUT_TORQUE, data=torque, is_extended_id=False
        ),
        can.Message(arbitration_id=EXTENDED_ID, data=torque, is_extended_id=True),
    ]
    end = time.monotonic() + a.seconds
    try:
        while time.monotonic() < end:
            for f in frames:
                bus.send(f)
            time.sleep(0.01)
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

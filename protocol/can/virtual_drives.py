"""Two virtual ODrives on a python-can bus: :class:`VirtualDrivePair` at the edge of a bus.

``python -m protocol.can.virtual_drives`` runs them with a toy motor (rotor inertia only, so
velocity ramps with the applied torque) until SIGINT/SIGTERM, then prints a JSON summary.
The plant emulator drives :class:`VirtualDrivePair` itself with the robot's wheel rates.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time

from protocol.can.bus_factory import add_bus_arguments
from protocol.can.drive_link import from_message, to_message
from protocol.can.drive_profile import VirtualDrivePair


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    add_bus_arguments(p)
    p.add_argument("--torque-limit", type=float, default=1.0, help="motor torque limit, Nm")
    p.add_argument("--rotor-inertia", type=float, default=1e-3, help="kg m^2 of the toy motor")
    p.add_argument("--heartbeat-period", type=float, default=0.1)
    p.add_argument("--encoder-period", type=float, default=0.01)
    a = p.parse_args(argv)

    from protocol.can.bus_factory import open_bus_from_args

    stop = False

    def on_signal(signum, frame):
        nonlocal stop
        stop = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    bus = open_bus_from_args(a)
    pair = VirtualDrivePair(
        a.node_right, a.node_left, a.torque_limit, a.heartbeat_period, a.encoder_period
    )
    motion = {n: [0.0, 0.0] for n in pair.drives}  # node -> [pos_rev, vel_rev_s]
    print(json.dumps({"ready": True}), flush=True)
    last = time.monotonic()
    try:
        while not stop:
            msg = bus.recv(timeout=0.002)
            now = time.monotonic()
            dt, last = now - last, now
            for node, drive in pair.drives.items():
                state = motion[node]
                state[1] += drive.torque / a.rotor_inertia * dt / (2.0 * math.pi)
                state[0] += state[1] * dt
            estimates = {n: (s[0], s[1]) for n, s in motion.items()}
            answers = pair.receive(from_message(msg), estimates) if msg is not None else []
            for frame in answers + pair.due_frames(now, estimates):
                bus.send(to_message(frame), timeout=0.1)
    finally:
        bus.shutdown()
    summary = {
        "drives": {
            str(n): {
                "axis_state": int(d.axis_state),
                "axis_error": d.axis_error,
                "control_mode": int(d.control_mode),
                "vel_rev_s": motion[n][1],
            }
            for n, d in pair.drives.items()
        },
        "rejections": pair.rejections.snapshot(),
        "ignored": dict(pair.ignored),
    }
    print(json.dumps(summary), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

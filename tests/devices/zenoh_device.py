"""A test device over Zenoh with known behaviours, sharing no code with the bench (only
``eclipse-zenoh`` and ``msgpack``, the messages as docs/protocol.md spells them).

Modes (each a known answer for the bench's figures at its edge):
- default: one TorqueCommand per State received, naming it;
- ``--wait-ms W``: the same, W ms after each State's arrival (a response time raised by W);
- ``--hz F --jitter-ms J``: commands at F Hz of its own, each send time moved by a uniform
  draw in [-J, +J] ms around its slot, naming the newest State it has;
- ``--stall-at T --stall-ms S``: once, T s after the first State, nothing is sent for S ms
  (the device's stall).
- ``--log FILE``: each command's seq and send time (its own CLOCK_MONOTONIC, ns) written to
  FILE at exit, for a test to compare what the bench measured with what the device did (the
  bench never reads it).
- ``--fifo``: the device runs SCHED_FIFO (a real-time device), so that its own response does
  not vary with the host's load and an added delay reads as itself;
- ``--garbage``: also publishes malformed payloads (not msgpack, wrong types, NaN torques)
  beside its commands, which the bench must count and refuse.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import threading
import time

import msgpack
import zenoh

STATE, TORQUE_COMMAND, VERSION = 1, 2, 1


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("endpoint")
    ap.add_argument("--robot", default="robot0")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--wait-ms", type=float, default=0.0)
    ap.add_argument("--hz", type=float, default=0.0)
    ap.add_argument("--jitter-ms", type=float, default=0.0)
    ap.add_argument("--stall-at", type=float, default=-1.0)
    ap.add_argument("--stall-ms", type=float, default=0.0)
    ap.add_argument("--tau", type=float, default=0.05, help="constant torque asked (N·m)")
    ap.add_argument("--garbage", action="store_true")
    ap.add_argument("--log", default="")
    ap.add_argument(
        "--fifo", action="store_true", help="run SCHED_FIFO (every thread, Zenoh's included)"
    )
    args = ap.parse_args()
    if args.fifo:  # before the session: its threads inherit the policy
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    # Wait for the bench, and reconnect to it after each run (a campaign restarts it).
    conf.insert_json5("connect/timeout_ms", "-1")
    conf.insert_json5("connect/exit_on_failure", "false")
    session = zenoh.open(conf)
    pub = session.declare_publisher(f"hil/{args.robot}/cmd/torque")
    lock = threading.Lock()
    newest: list = []  # [state_seq, sample_ns]
    first_ns: list[int] = []
    seq = 0
    stalled = False
    sent: list[tuple[int, int]] = []  # (seq, send ns): --log
    stop = threading.Event()

    def send(state_seq: int, sample_ns: int) -> None:
        nonlocal seq
        now = time.monotonic_ns()
        out = [
            TORQUE_COMMAND,
            VERSION,
            args.robot,
            seq,
            state_seq,
            sample_ns,
            now,
            now,
            float(args.tau),
            0.0,
            "test_device",
            0,
        ]
        seq += 1
        pub.put(msgpack.packb(out, use_bin_type=True))
        sent.append((seq - 1, now))
        if args.garbage and seq % 10 == 0:
            pub.put(b"\xc1not msgpack")
            bad = [
                TORQUE_COMMAND,
                VERSION,
                args.robot,
                seq,
                state_seq,
                sample_ns,
                now,
                now,
                float("nan"),
                0.0,
                "test_device",
                0,
            ]
            pub.put(msgpack.packb(bad, use_bin_type=True))
            pub.put(msgpack.packb([TORQUE_COMMAND, VERSION, args.robot, "x"]))

    def maybe_stall() -> None:
        nonlocal stalled
        due = first_ns and time.monotonic_ns() - first_ns[0] >= args.stall_at * 1e9
        if args.stall_at >= 0 and not stalled and due:
            stalled = True
            time.sleep(args.stall_ms / 1e3)

    def on_state(sample: zenoh.Sample) -> None:
        msg = msgpack.unpackb(sample.payload.to_bytes())
        if msg[:2] != [STATE, VERSION]:
            return
        with lock:
            if not first_ns:
                first_ns.append(time.monotonic_ns())
            newest[:] = [msg[3], msg[4]]
        if args.hz:
            return
        arrived = time.monotonic()
        with lock:
            maybe_stall()
            if args.wait_ms:
                # a busy wait: a sleep's wake-up lateness would blur the known answer
                while time.monotonic() - arrived < args.wait_ms / 1e3:
                    pass
            send(msg[3], msg[4])

    sub = session.declare_subscriber(f"hil/{args.robot}/state", on_state)
    try:
        end = time.monotonic() + args.duration
        if args.hz:
            period = 1.0 / args.hz
            while not first_ns and time.monotonic() < end:
                time.sleep(0.001)
            k0 = time.monotonic()
            k = 0
            while time.monotonic() < end:
                k += 1
                due = k0 + k * period + random.uniform(-args.jitter_ms, args.jitter_ms) / 1e3
                if time.monotonic() > due + period:
                    continue  # a slot missed by a stall is skipped, not sent in a burst
                while time.monotonic() < due:  # busy: the known answer is the draw
                    pass
                with lock:
                    maybe_stall()
                    if newest:
                        send(*newest)
        else:
            time.sleep(args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        sub.undeclare()
        session.close()
        if args.log:
            with open(args.log, "w") as f:
                f.writelines(f"{k} {t}\n" for k, t in sent)


if __name__ == "__main__":
    main()

"""A controller of your own over Zenoh, written only from docs/protocol.md.

It imports nothing of this project: only ``eclipse-zenoh`` and ``msgpack``. Start the bench
first, then this, with the endpoint the bench printed::

    hil run --controller external --duration 10        # prints: connect to tcp/127.0.0.1:PORT
    python examples/zenoh_controller.py tcp/127.0.0.1:PORT

The law is deliberately simple (a speed loop for each of v and omega toward a constant
circle: v = 0.5 m/s, omega = 0.5 rad/s): the point is the protocol. Each State received is
answered by one TorqueCommand that names it (``state_seq``, ``state_sample_time_ns``), which
lets the bench measure the exact age of every command it applies.
"""

from __future__ import annotations

import argparse
import json
import threading
import time

import msgpack
import zenoh

STATE, TORQUE_COMMAND, VERSION = 1, 2, 1  # docs/protocol.md: type tags, schema version
V_REF, OMEGA_REF = 0.5, 0.5  # m/s, rad/s
K_V, K_OMEGA = 2.0, 0.5  # torque per unit of speed error
TAU_MAX = 0.4  # stay inside the scenario's torque limits (2)


def clip(x: float, limit: float) -> float:
    return max(-limit, min(limit, x))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("endpoint", help="the bench's Zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--robot", default="robot0", help="the robot's id (hil/<robot>/...)")
    ap.add_argument("--duration", type=float, default=3600.0, help="s to run, then exit")
    args = ap.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    # Wait for the bench, and reconnect to it after each run (a campaign restarts it).
    conf.insert_json5("connect/timeout_ms", "-1")
    conf.insert_json5("connect/exit_on_failure", "false")  # no packet leaves the host
    session = zenoh.open(conf)
    pub = session.declare_publisher(f"hil/{args.robot}/cmd/torque")
    seq = 0
    lock = threading.Lock()

    def on_state(sample: zenoh.Sample) -> None:
        nonlocal seq
        msg = msgpack.unpackb(sample.payload.to_bytes())
        if msg[:2] != [STATE, VERSION]:
            return  # not a State of the version this controller knows
        _robot, state_seq, sample_ns, _send_ns, _x, _y, _theta, v, omega = msg[2:11]
        start = time.monotonic_ns()
        tau1 = clip(K_V * (V_REF - v), TAU_MAX)
        tau2 = clip(K_OMEGA * (OMEGA_REF - omega), TAU_MAX)
        with lock:
            out = [
                TORQUE_COMMAND,
                VERSION,
                args.robot,
                seq,
                state_seq,
                sample_ns,
                start,
                time.monotonic_ns(),
                float(tau1),
                float(tau2),
                "example",
                0,
            ]
            seq += 1
        pub.put(msgpack.packb(out, use_bin_type=True))

    sub = session.declare_subscriber(f"hil/{args.robot}/state", on_state)
    try:
        time.sleep(args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        sub.undeclare()
        session.close()


if __name__ == "__main__":
    main()

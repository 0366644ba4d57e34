"""A Zenoh session that tries what it should not: ``python -m tests.intruder ENDPOINT [options]``.

It opens a client session of the run's router with whatever credentials its environment holds
(``HIL_ZENOH_CREDENTIALS`` or ``HIL_ZENOH_USER``/``HIL_ZENOH_PASSWORD``, as every service
does; none at all is an intruder too) and publishes ``--kind`` messages on robot ``--robot``'s
key at ``--rate`` Hz for ``--duration`` s (or ``--count`` messages), numbered from ``--seq0``,
with a distinctive torque ``--tau1``. A session the router refuses is retried at every tick
(every attempt is a fresh authentication), so an intruder that ever got in would publish.
``--robot-id`` puts another robot's id in the messages than the key says (a forged message).
``--subscribe`` also subscribes to ``hil/**`` and counts the states it receives.

Prints one JSON line: opened, open_attempts, refusals, published, states_received.
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def main(argv: list[str] | None = None) -> int:
    import zenoh

    from protocol import keys
    from protocol.messages import State, TorqueCommand, encode
    from runtime.zsession import open_session

    ap = argparse.ArgumentParser()
    ap.add_argument("endpoint")
    ap.add_argument("--robot", default="robot0")
    ap.add_argument("--robot-id", default=None, help="robot id in the messages (default --robot)")
    ap.add_argument("--kind", choices=("torque", "state"), default="torque")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--count", type=int, default=0, help="stop after this many puts (0: none)")
    ap.add_argument("--seq0", type=int, default=9_000_000)
    ap.add_argument("--tau1", type=float, default=1.2345)
    ap.add_argument("--subscribe", action="store_true")
    a = ap.parse_args(argv)
    rid = a.robot_id or a.robot
    key = keys.torque_key(a.robot) if a.kind == "torque" else keys.state_key(a.robot)
    out = {"opened": False, "open_attempts": 0, "refusals": 0, "published": 0}
    out["states_received"] = 0
    session = pub = None

    def on_sample(sample) -> None:
        if str(sample.key_expr).endswith("/state"):
            out["states_received"] += 1

    period = 1.0 / a.rate
    t0 = time.monotonic()
    i = 0
    while time.monotonic() - t0 < a.duration and (a.count <= 0 or out["published"] < a.count):
        if session is None:
            out["open_attempts"] += 1
            try:
                session = open_session(a.endpoint, mode="client")
            except zenoh.ZError:
                out["refusals"] += 1
            else:
                out["opened"] = True
                # BLOCK: what the router lets through is never lost on the way, so a count
                # at the receiver is exact.
                pub = session.declare_publisher(
                    key, congestion_control=zenoh.CongestionControl.BLOCK, express=True
                )
                if a.subscribe:
                    session.declare_subscriber(keys.ALL_ROBOTS, on_sample)
        if pub is not None:
            now = time.monotonic_ns()
            seq = a.seq0 + i
            if a.kind == "torque":
                msg = TorqueCommand(rid, seq, seq, now, now, now, a.tau1, -a.tau1, "intruder")
            else:
                msg = State(rid, seq, now, now, a.tau1, 0.0, 0.0, 0.0, 0.0)
            pub.put(encode(msg))
            out["published"] += 1
        i += 1
        delay = t0 + i * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
    if session is not None:
        time.sleep(0.2)  # let the last puts leave and late states arrive
        session.close()
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

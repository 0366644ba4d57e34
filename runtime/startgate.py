"""The start handshake: both services say "ready", then ``hil run`` announces the epoch.

Process start-up (imports, Zenoh links, CAN arming) takes a variable second or so; a fixed
epoch would make a slow start look like deadline misses. A service started while its peer is
already running (a restart after a crash) joins the run: the peer's periodic Status carries the
epoch. So each service publishes
``Status(role, "ready")`` until it hears ``Status(role="run", state="start",
counters={"epoch_ns": ...})`` on the robot's status key; the epoch (a ``time.monotonic_ns()``
value a little in the future) is the run's t = 0 for both.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from protocol import keys
from protocol.messages import Status, decode_as, encode

READY_WITHIN_S = 5.0  # a readiness condition that never holds delays the start this long


class StartGate:
    def __init__(self, session: Any, robot_id: str, role: str) -> None:
        from runtime.zsession import payload_bytes, publisher

        self.robot_id = robot_id
        self.role = role
        self._pub = publisher(session, keys.status_key(robot_id))
        self._epoch: int | None = None
        self._event = threading.Event()
        self._payload = payload_bytes
        self._sub = session.declare_subscriber(keys.status_key(robot_id), self._on_status)
        self._seq = 0
        self.joined = False

    def _on_status(self, sample: Any) -> None:
        try:
            msg = decode_as(Status, self._payload(sample))
        except ValueError:
            return
        if msg.role == "run" and msg.state == "start" and "epoch_ns" in msg.counters:
            self._epoch = int(msg.counters["epoch_ns"])
            self._event.set()
        elif (
            msg.role != self.role
            and msg.state == "running"
            and int(msg.counters.get("epoch_ns", 0)) > 0
        ):
            # A peer already running: this service was restarted mid-run and joins the run.
            self._epoch = int(msg.counters["epoch_ns"])
            self.joined = True
            self._event.set()

    def wait(
        self,
        stop: Any,
        timeout: float = 60.0,
        idle: Callable[[], None] | None = None,
        ready: Callable[[], bool] | None = None,
    ) -> int | None:
        """Announce readiness every 50 ms until the epoch arrives; None on stop/timeout.
        ``ready``: readiness is announced only once it holds (e.g. the controller's command
        publisher has the plant's subscriber: through routers a route forms some time after
        both declared), or after :data:`READY_WITHIN_S` in any case."""
        start = time.monotonic()
        deadline = start + timeout
        while not stop and time.monotonic() < deadline:
            if ready is None or time.monotonic() - start > READY_WITHIN_S or ready():
                now = time.monotonic_ns()
                self._pub.put(encode(Status(self.robot_id, self._seq, now, self.role, "ready")))
                self._seq += 1
            if self._event.wait(0.05):
                break
            if idle is not None:
                idle()
        self._sub.undeclare()
        return self._epoch


def announce_start(session: Any, robot_id: str, epoch_ns: int, seq: int = 0) -> None:
    from runtime.zsession import publisher

    pub = publisher(session, keys.status_key(robot_id))
    pub.put(
        encode(
            Status(
                robot_id, seq, time.monotonic_ns(), "run", "start", 0, {"epoch_ns": int(epoch_ns)}
            )
        )
    )

"""Clock offset to the plant's host, measured continuously over Zenoh (docs/clocks.md).

Every stamp of the bench is its own host's ``CLOCK_MONOTONIC``. Two hosts' monotonic clocks
share no origin, so a figure made of stamps from two hosts means nothing until their offset is
known. The plant answers pings on ``hilclock/<robot>/ping`` with pongs on
``hilclock/<robot>/pong`` (:class:`ClockEcho`, in a Zenoh callback: never on its real-time
thread); any other process polls it a few times a second (:class:`ClockProbe`, a thread of its
own) with NTP's on-wire exchange of four timestamps (RFC 5905, section 8):

- t1: the probe sends the query (probe clock), t2: the echo receives it, t3: the echo replies
  (plant clock), t4: the probe receives the reply (probe clock);
- offset theta = ((t2 - t1) + (t3 - t4)) / 2, the plant clock minus the probe's;
- round-trip delay delta = (t4 - t1) - (t3 - t2).

Since t1 <= t2' and t3' <= t4 in real time, the true offset lies within theta +- delta / 2
whatever the two paths' asymmetry: half the round trip is the estimate's uncertainty, a bound,
not a standard deviation. Of the last :data:`FILTER_SAMPLES` exchanges the one with the least
delay is kept (RFC 5905, section 10, "Clock Filter Algorithm": the sample with the smallest
delay has the smallest error bound). A plant stamp converts to the probe's clock as
``t_probe = t_plant - offset`` (:meth:`Estimate.to_local`).

Each poll is a burst of :data:`BURST` exchanges back to back, as NTP's burst mode sends several
packets per poll (RFC 5905, section 13), but without its spacing: a lone ping after a quiet
interval pays, on its way out only, the wake-up of every idle thread and CPU on its path, and
the asymmetry biases its offset by half of that (about 0.2-0.35 ms measured between lab hosts
at 20 ms polls, against tens of microseconds when the path is awake). The first exchange of a
burst wakes the path, the next ones cross it awake, and the filter keeps the least delayed.

The probe writes every exchange and the filter's estimate to a CSV file (one line each,
flushed), the run folder's ``clock-<role>.csv``.
"""

from __future__ import annotations

import contextlib
import secrets
import struct
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocol import keys
from protocol.hoplog import CLOCK_FILE as CLOCK_FILE  # the controller's probe, in the run folder

FILTER_SAMPLES = 8  # RFC 5905's clock filter register
BURST = 4  # exchanges per poll, back to back: the register holds the last two polls
INTERVAL_S = 0.25  # between polls
REPLY_TIMEOUT_S = 0.25  # a pong later than this is no use to the filter anyway
FIRST_ESTIMATE_S = 3.0  # how long a service waits for its first estimate before "ready"
CLOCK_PREFIX = "hilclock"  # not under hil/: recorders of hil/** never see the exchanges
_PING = struct.Struct("<Qq")  # the probe's token, t1
_PONG = struct.Struct("<Qqqq")  # the probe's token, t1, t2, t3
COLUMNS = ("t1_ns", "t2_ns", "t3_ns", "t4_ns", "offset_ns", "delay_ns", "best_offset_ns")
COLUMNS += ("uncertainty_ns",)


def ping_key(robot_id: str) -> str:
    """``hilclock/<robot_id>/ping``: probes' requests to the plant's clock echo."""
    return f"{CLOCK_PREFIX}/{keys.validate_robot_id(robot_id)}/ping"


def pong_key(robot_id: str) -> str:
    """``hilclock/<robot_id>/pong``: the echo's answers (each probe keeps its own token's)."""
    return f"{CLOCK_PREFIX}/{keys.validate_robot_id(robot_id)}/pong"


def _publisher(session: Any, key: str) -> Any:
    import zenoh  # here: hil.measure reads this module's file layout without loading Zenoh

    # Express: a batch would add its own wait to one direction only.
    return session.declare_publisher(key, express=True, priority=zenoh.Priority.REAL_TIME)


@dataclass(frozen=True)
class Exchange:
    """One four-timestamp exchange (nanoseconds; t1, t4 probe clock; t2, t3 plant clock)."""

    t1: int
    t2: int
    t3: int
    t4: int

    @property
    def offset_ns(self) -> float:
        return ((self.t2 - self.t1) + (self.t3 - self.t4)) / 2

    @property
    def delay_ns(self) -> int:
        return (self.t4 - self.t1) - (self.t3 - self.t2)


@dataclass(frozen=True)
class Estimate:
    """The plant clock minus the local clock, +- ``uncertainty_ns`` (half the round trip of
    the exchange it comes from), as of ``at_ns`` (local clock)."""

    offset_ns: float
    uncertainty_ns: float
    at_ns: int

    def to_local(self, plant_ns: float) -> float:
        return plant_ns - self.offset_ns


class ClockFilter:
    """RFC 5905's minimum-delay clock filter over the last ``size`` exchanges."""

    def __init__(self, size: int = FILTER_SAMPLES) -> None:
        self.samples: deque[Exchange] = deque(maxlen=size)

    def add(self, ex: Exchange) -> Estimate:
        self.samples.append(ex)
        best = min(self.samples, key=lambda e: e.delay_ns)
        return Estimate(best.offset_ns, best.delay_ns / 2, ex.t4)


class ClockEcho:
    """The plant's side: stamps t2 on a ping's arrival and t3 just before its pong. Both
    directions are a put through a declared publisher and a subscriber's callback, so they
    cost the same (a query's ``get`` costs ~0.1 ms more than its reply, which would bias the
    offset by half of that)."""

    def __init__(self, session: Any, robot_id: str) -> None:
        self.answered = 0
        self._pong = _publisher(session, pong_key(robot_id))
        self._sub = session.declare_subscriber(ping_key(robot_id), self._on_ping)

    def _on_ping(self, sample: Any) -> None:
        t2 = time.monotonic_ns()
        raw = bytes(sample.payload.to_bytes())
        if len(raw) != _PING.size:
            return  # not an exchange: no answer
        token, t1 = _PING.unpack(raw)
        self._pong.put(_PONG.pack(token, t1, t2, time.monotonic_ns()))
        self.answered += 1

    def close(self) -> None:
        with contextlib.suppress(Exception):  # the session may be closed already
            self._sub.undeclare()
            self._pong.undeclare()


class ClockProbe:
    """A thread polling the plant's echo (a burst of :data:`BURST` exchanges) every
    ``interval`` seconds; the newest estimate is :attr:`estimate` (None until the first
    answer). Every exchange goes to ``csv_path``."""

    def __init__(
        self,
        session: Any,
        robot_id: str,
        csv_path: Path | None = None,
        interval: float = INTERVAL_S,
    ) -> None:
        self.interval = interval
        self.filter = ClockFilter()
        self.estimate: Estimate | None = None
        self.exchanges = 0
        self._token = secrets.randbits(64)
        self._pending = 0  # t1 of the ping awaiting its pong
        self._got: Exchange | None = None
        self._answered = threading.Event()
        self._ping = _publisher(session, ping_key(robot_id))
        self._sub = session.declare_subscriber(pong_key(robot_id), self._on_pong)
        self._file = None if csv_path is None else csv_path.open("a", buffering=1)
        if self._file is not None and self._file.tell() == 0:
            self._file.write(",".join(COLUMNS) + "\n")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="clock-probe", daemon=True)

    def start(self) -> ClockProbe:
        self._thread.start()
        return self

    def wait_first(self, timeout: float = FIRST_ESTIMATE_S) -> Estimate | None:
        """The first estimate, waiting up to ``timeout`` s for it (None: no echo answered)."""
        deadline = time.monotonic() + timeout
        while self.estimate is None and time.monotonic() < deadline:
            time.sleep(0.005)
        return self.estimate

    def _on_pong(self, sample: Any) -> None:
        t4 = time.monotonic_ns()  # first: the callback's own work is not round trip
        raw = bytes(sample.payload.to_bytes())
        if len(raw) != _PONG.size:
            return
        token, t1, t2, t3 = _PONG.unpack(raw)
        if token == self._token and t1 == self._pending:  # ours, and not a late one
            self._got = Exchange(t1, t2, t3, t4)
            self._answered.set()

    def exchange(self) -> Exchange | None:
        """One exchange, or None when no answer came within :data:`REPLY_TIMEOUT_S`."""
        self._answered.clear()
        self._got = None
        t1 = self._pending = time.monotonic_ns()
        self._ping.put(_PING.pack(self._token, t1))
        self._answered.wait(REPLY_TIMEOUT_S)
        return self._got

    def record(self, ex: Exchange) -> Estimate:
        """Add an exchange to the filter and the file; the filter's new estimate."""
        est = self.estimate = self.filter.add(ex)
        self.exchanges += 1
        if self._file is not None:
            row = (ex.t1, ex.t2, ex.t3, ex.t4, round(ex.offset_ns), ex.delay_ns)
            row += (round(est.offset_ns), round(est.uncertainty_ns))
            self._file.write(",".join(map(str, row)) + "\n")
        return est

    def poll(self) -> int:
        """One burst of :data:`BURST` exchanges, each recorded; how many were answered."""
        answered = 0
        for _ in range(BURST):
            ex = self.exchange()
            if ex is not None:
                self.record(ex)
                answered += 1
        return answered

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.poll()
            except Exception:  # a closing session: the probe ends, the service does not
                return
            self._stop.wait(self.interval)

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(REPLY_TIMEOUT_S + 1.0)
        with contextlib.suppress(Exception):
            self._sub.undeclare()
            self._ping.undeclare()
        if self._file is not None:
            self._file.close()


def clocks_differ(est: Estimate | None) -> bool:
    """True when the estimate proves the two clocks differ: 0 lies outside offset +- its
    uncertainty. One host's estimate always holds 0 (the bound is exact), so there nothing is
    ever converted."""
    return est is not None and abs(est.offset_ns) > est.uncertainty_ns


def epoch_on_local_clock(epoch_ns: int, probe: ClockProbe) -> int:
    """An epoch announced on the plant's clock, on this process' clock (unchanged unless the
    clocks provably differ)."""
    est = probe.estimate
    return round(est.to_local(epoch_ns)) if clocks_differ(est) and est else epoch_ns


def _main(argv: list[str]) -> int:
    """``python -m runtime.clocksync echo|probe ROBOT ENDPOINT [COUNT]``: the echo until
    stopped, or at least COUNT exchanges (whole bursts) printed as JSON (a client of the router
    at ENDPOINT)."""
    import json
    import signal

    from runtime.zsession import open_session

    if len(argv) not in (3, 4) or argv[0] not in ("echo", "probe"):
        print(_main.__doc__, file=sys.stderr)
        return 2
    session = open_session(argv[2], mode="client", credentials=None)
    try:
        if argv[0] == "echo":
            done = threading.Event()
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: done.set())
            echo = ClockEcho(session, argv[1])
            print("echo up", flush=True)
            while not done.wait(0.5):
                pass
            echo.close()
            return 0
        probe = ClockProbe(session, argv[1], interval=0.02)
        count = int(argv[3]) if len(argv) == 4 else 20
        while probe.exchanges < count:
            if probe.poll() == 0:
                print("no answer from the plant's clock echo", file=sys.stderr)
                return 1
            time.sleep(probe.interval)
        est = probe.estimate
        assert est is not None
        out = {"offset_ns": est.offset_ns, "uncertainty_ns": est.uncertainty_ns}
        out["exchanges"] = [(e.offset_ns, e.delay_ns) for e in probe.filter.samples]
        print(json.dumps(out), flush=True)
        return 0
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))

"""A raw python-can peer: the baseline of the virtual drives in bench/bench_drive_echo.py.

It imports python-can and the standard library only (tests/test_drive_echo_bench.py checks it):
what it costs to answer a request and to keep a period is what python-can and Python cost on
this bus, with no drive model behind it.

- Echo: every remote (RTR) frame whose id is one of ``--answer`` is answered with one 8-byte
  data frame of the same id, as an ODrive answers a ``Get_*`` request.
- Cyclic: each ``--cyclic ID:MS`` frame (8 bytes) is sent every MS ms: ``--cyclic-mode loop``
  (default) from ONE thread on absolute deadlines, every frame due at a deadline sent at once
  (the drives' cyclic sender's shape, without the model); ``send_periodic`` with python-can's own
  ``bus.send_periodic`` (a thread per frame on most interfaces; on SocketCAN the kernel's
  broadcast manager sends, a stricter baseline than any Python loop).
- ``--scheduling fifo`` applies what the drives' process applies to itself
  (runtime/realtime.py's ``setup_scheduling``): GIL switch interval 0.5 ms, the CPU latency
  request held at 0 us, every page locked, the collector's objects frozen, SCHED_FIFO 80 for
  the threads that serve the bus (the main thread, which answers, and the cyclic sender) and
  79 for every other thread (python-can's and Zenoh's helpers), as the drives' reader and
  cyclic sender run at 80 (runtime.realtime.raise_threads).

Known-answer injections (tests only; off by default): ``--answer ID:DELAY_MS`` waits DELAY_MS
before answering that id; ``--late-every K --late-ms D`` sends every K-th frame of each cyclic
id D ms after its deadline (loop mode).

Prints ``ready`` once the bus is open and the cyclic frames run; stops on SIGINT or SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import gc
import os
import signal
import sys
import threading
import time

import can

READY = "ready"
REPLY = bytes(8)
GIL_SWITCH_S = 0.0005  # as runtime.realtime.GIL_SWITCH_S
FIFO_PRIORITY = 80
MCL_CURRENT, MCL_FUTURE = 1, 2


def apply_scheduling(
    policy: str, serving: tuple[int, ...] = (), priority: int = FIFO_PRIORITY
) -> list[str]:
    """``policy`` ("fifo" or "other") for this process as the drives apply theirs (module
    docstring): ``priority`` for the calling thread and the ``serving`` threads (native ids),
    one below for every other; what could not be applied, as text (empty: all of it)."""
    if policy != "fifo":
        return []
    errors = []
    sys.setswitchinterval(GIL_SWITCH_S)
    try:
        fd = os.open("/dev/cpu_dma_latency", os.O_WRONLY | os.O_CLOEXEC)
        os.write(fd, (0).to_bytes(4, "little"))  # held until the process exits
    except OSError as exc:
        errors.append(f"cpu latency: {exc}")
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        errors.append(f"mlockall: {os.strerror(ctypes.get_errno())}")
    gc.collect()
    gc.freeze()
    top = {threading.get_native_id(), *serving}
    for tid in (int(t) for t in os.listdir("/proc/self/task")):
        prio = priority if tid in top else priority - 1
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(prio))
        except OSError as exc:
            errors.append(f"SCHED_FIFO for thread {tid}: {exc}")
    return errors


def open_bus(interface: str, channel: str, endpoint: str | None, bitrate: int) -> can.BusABC:
    """The bus as the drives open it: zenoh_can with its endpoint and bit-time model; SocketCAN
    and udp_multicast as they are."""
    kw: dict = {"interface": interface, "channel": channel}
    if interface == "zenoh_can":
        kw.update(endpoint=endpoint, bitrate=bitrate or None)
    return can.Bus(**kw)


def _id_ms(text: str) -> tuple[int, float]:
    ident, _, ms = text.partition(":")
    return int(ident, 0), float(ms or 0.0)


def cyclic_loop(
    bus: can.BusABC,
    frames: list[tuple[int, float]],
    stop: threading.Event,
    late_every: int = 0,
    late_s: float = 0.0,
) -> None:
    """Send each (id, period ms) on absolute deadlines from this thread (module docstring)."""
    start = time.monotonic()
    due = {ident: start for ident, _ in frames}
    period = {ident: ms / 1000.0 for ident, ms in frames}
    sent = dict.fromkeys(due, 0)
    while not stop.is_set():
        wait = min(due.values()) - time.monotonic()
        if wait > 0.0:
            time.sleep(wait)
            continue
        now = time.monotonic()
        for ident, deadline in due.items():
            if deadline > now:
                continue
            sent[ident] += 1
            if late_every and sent[ident] % late_every == 0:
                time.sleep(max(0.0, deadline + late_s - time.monotonic()))
            with contextlib.suppress(can.CanError):
                bus.send(can.Message(arbitration_id=ident, data=REPLY, is_extended_id=False))
            nxt = deadline + period[ident]
            # as the drives: on the grid, restarted from now after a stall of 10 periods
            due[ident] = nxt if nxt > now - 10 * period[ident] else now + period[ident]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--interface", default="zenoh_can")
    p.add_argument("--channel", default="hil0")
    p.add_argument("--endpoint", default=None, help="zenoh_can's endpoint")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="zenoh_can's bit-time model")
    p.add_argument("--answer", action="append", default=[], metavar="ID[:DELAY_MS]")
    p.add_argument("--cyclic", action="append", default=[], metavar="ID:MS")
    p.add_argument("--cyclic-mode", choices=("loop", "send_periodic"), default="loop")
    p.add_argument("--late-every", type=int, default=0)
    p.add_argument("--late-ms", type=float, default=0.0)
    p.add_argument("--scheduling", choices=("fifo", "other"), default="other")
    a = p.parse_args(argv)
    answers = {ident: ms / 1000.0 for ident, ms in map(_id_ms, a.answer)}
    cyclic = [_id_ms(c) for c in a.cyclic]
    stopped = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stopped.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    bus = open_bus(a.interface, a.channel, a.endpoint, a.bitrate)
    tasks = []
    senders: list[threading.Thread] = []
    try:
        if cyclic and a.cyclic_mode == "loop":
            late = (a.late_every, a.late_ms / 1000.0)
            senders.append(
                threading.Thread(
                    target=cyclic_loop, args=(bus, cyclic, stopped, *late), daemon=True
                )
            )
            senders[0].start()
        else:
            for ident, ms in cyclic:
                msg = can.Message(arbitration_id=ident, data=REPLY, is_extended_id=False)
                tasks.append(bus.send_periodic(msg, ms / 1000.0))
                if isinstance(getattr(tasks[-1], "thread", None), threading.Thread):
                    senders.append(tasks[-1].thread)  # python-can's thread (not the BCM's)
        serving = tuple(t.native_id for t in senders if t.native_id is not None)
        for error in apply_scheduling(a.scheduling, serving):
            print(f"warning: {error}", file=sys.stderr, flush=True)
        print(READY, flush=True)
        while not stopped.is_set():
            msg = bus.recv(0.1)
            if msg is None or not msg.is_remote_frame:
                continue
            delay = answers.get(msg.arbitration_id)
            if delay is None:
                continue
            if delay:
                time.sleep(delay)
            reply = can.Message(arbitration_id=msg.arbitration_id, data=REPLY, is_extended_id=False)
            with contextlib.suppress(can.CanError):
                bus.send(reply)
    finally:
        stopped.set()
        for task in tasks:
            task.stop()
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The real-time shell's timing primitives: scheduling set-up and an absolute-deadline clock.

The control law (7)-(10) is sampled: its guarantees under sampling need the longest gap Ts
between sample times and the sample-to-apply latency delta small and known (docs/design.md,
section 2). So the loop

- wakes on absolute deadlines ``start + k * period`` of ``CLOCK_MONOTONIC`` (no drift: a late
  wake-up never shifts later deadlines), sleeping with ``clock_nanosleep(TIMER_ABSTIME)`` up to
  ``spin_ns`` before the deadline and spinning the rest when that measurably helps;
- where permitted runs SCHED_FIFO, pinned to one CPU, with memory locked (``mlockall``) and the
  garbage collector frozen and disabled, keeps the CPUs out of idle states that are slow to
  leave (PM QoS ``/dev/cpu_dma_latency``, as cyclictest does), and reports what it got.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import os
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any

CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1
MCL_CURRENT = 1
MCL_FUTURE = 2
PM_QOS_CPU_LATENCY = "/dev/cpu_dma_latency"


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


def _load_libc() -> ctypes.CDLL | None:
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    except OSError:
        return None


_LIBC = _load_libc()
_NANOSLEEP = getattr(_LIBC, "clock_nanosleep", None) if _LIBC is not None else None


def sleep_until_ns(deadline_ns: int) -> None:
    """Sleep until ``time.monotonic_ns() >= deadline_ns`` (absolute, immune to drift)."""
    if _NANOSLEEP is not None:
        ts = _Timespec(deadline_ns // 1_000_000_000, deadline_ns % 1_000_000_000)
        # EINTR: a signal handler ran; the loop above re-checks the clock, so just return.
        _NANOSLEEP(CLOCK_MONOTONIC, TIMER_ABSTIME, ctypes.byref(ts), None)
        return
    delay = deadline_ns - time.monotonic_ns()
    if delay > 0:
        time.sleep(delay / 1e9)


def wait_until_ns(deadline_ns: int, spin_ns: int = 0) -> int:
    """Sleep to ``deadline_ns - spin_ns``, spin the rest; returns the wake-up time (ns)."""
    if spin_ns > 0:
        sleep_until_ns(deadline_ns - spin_ns)
        now = time.monotonic_ns()
        while now < deadline_ns:
            now = time.monotonic_ns()
        return now
    sleep_until_ns(deadline_ns)
    return time.monotonic_ns()


@dataclass
class Tick:
    """One wake-up: the slot k it was due for, that slot's deadline, when the loop woke, and
    how many later slots it skipped (their deadlines passed while it was late).

    The lateness ``wake_ns - deadline_ns`` is never re-based: a tick that wakes 11.7 ms after
    its deadline reports 11.7 ms, as cyclictest would."""

    k: int
    deadline_ns: int
    wake_ns: int
    skipped: int

    @property
    def lateness_ns(self) -> int:
        return self.wake_ns - self.deadline_ns


class DeadlineClock:
    """Absolute deadlines ``start_ns + k * period_ns``.

    A tick that wakes a period or more after its deadline is a deadline miss. The slots whose
    deadlines passed meanwhile are skipped (counted, never run as a burst of catch-up cycles
    with stale data): the next tick is due at the first deadline still in the future.
    """

    def __init__(self, period_ns: int, start_ns: int, spin_ns: int = 0, first_k: int = 0) -> None:
        """Slot k is due at ``start_ns + k * period_ns``; the first tick is slot ``first_k``
        (a service that joins a run late starts at the first slot still ahead)."""
        if period_ns <= 0:
            raise ValueError("period must be positive")
        self.period_ns = int(period_ns)
        self.start_ns = int(start_ns)
        self.spin_ns = max(0, int(spin_ns))
        self.k = int(first_k) - 1
        self.misses = 0
        self.skipped = 0

    def due_ns(self) -> int:
        """The deadline of the tick :meth:`next` waits for (unless that one is missed)."""
        return self.start_ns + (self.k + 1) * self.period_ns

    def next(self) -> Tick:
        k = self.k + 1
        deadline = self.due_ns()
        wake = wait_until_ns(deadline, self.spin_ns)
        late_slots = (wake - deadline) // self.period_ns
        skipped = 0
        if late_slots >= 1:
            self.misses += 1
            skipped = int(late_slots)
            self.skipped += skipped
        self.k = k + skipped
        return Tick(k, deadline, wake, skipped)


@dataclass
class SchedulingReport:
    """What the process asked for and what it got (published in Status and the summary)."""

    requested: str = "other"
    policy: str = "SCHED_OTHER"
    priority: int = 0
    affinity: list[int] | None = None
    mlockall: bool = False
    gc_frozen: bool = False
    helper_threads: int = 0
    idle: str = "os"
    errors: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


# A loop thread that wakes at its deadline while another thread of its process (Zenoh's
# callback, the hop log's writer, another robot's loop) holds the GIL waits up to the switch
# interval for it: Python's default 5 ms is ten periods at 2 kHz. One robot, 2 kHz periodic,
# three runs each: the controller's wake-up max 1.7-9.5 ms with 5 ms, 0.42-0.56 ms with
# 0.5 ms (docs/realtime.md); 64 robots at 100 Hz in one process: wake-up p99 21 ms against
# 1.2 ms (docs/fleet.md).
GIL_SWITCH_S = 0.0005


def setup_scheduling(
    scheduling: str = "fifo",
    priority: int = 80,
    cpu: int | None = None,
    lock_memory: bool = True,
    freeze_gc: bool = True,
    idle: str = "poll",
) -> SchedulingReport:
    """Apply what the platform permits; never fail because a privilege is missing.

    ``idle="poll"`` holds the kernel's CPU latency request at 0 us for the life of the process
    (:func:`hold_cpu_latency`); ``"os"`` leaves the host's idle policy alone."""
    report = SchedulingReport(requested=scheduling)
    sys.setswitchinterval(GIL_SWITCH_S)
    if idle == "poll":
        try:
            hold_cpu_latency()
            report.idle = "poll"
        except OSError as exc:
            report.errors["idle"] = str(exc)
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
        except (OSError, ValueError) as exc:
            report.errors["affinity"] = str(exc)
    try:
        report.affinity = sorted(os.sched_getaffinity(0))
    except OSError:
        report.affinity = None
    if lock_memory and _LIBC is not None:
        if _LIBC.mlockall(MCL_CURRENT | MCL_FUTURE) == 0:
            report.mlockall = True
        else:
            report.errors["mlockall"] = os.strerror(ctypes.get_errno())
    if freeze_gc:
        # Everything built so far moves to the permanent generation; with the collector off
        # no cycle pays for a full collection mid-period.
        gc.collect()
        gc.freeze()
        gc.disable()
        report.gc_frozen = True
    # The real-time policy last: locking every page of the process (tens of ms for a service
    # with numpy and Zenoh loaded) and the full collection above would otherwise run at
    # FIFO 80 on the pinned CPU and stall every other real-time process there, another
    # bench run's service among them.
    if scheduling == "fifo":
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            report.policy = "SCHED_FIFO"
            report.priority = priority
        except (PermissionError, OSError, AttributeError) as exc:
            report.errors["fifo"] = str(exc)
            print(
                f"warning: SCHED_FIFO refused ({exc}): running SCHED_OTHER, so wake-up "
                "lateness and the command age are those of a time-shared host (root or "
                "CAP_SYS_NICE gives the real-time policy)",
                file=sys.stderr,
                flush=True,
            )
        else:
            # Every other thread of the process (Zenoh's runtime, the CAN readers) one step
            # below: they take the GIL to deliver messages, and a SCHED_OTHER thread holding
            # the GIL while preempted by outside load stalls the loop (priority inversion).
            report.helper_threads = _raise_helper_threads(priority - 1)
    return report


def _raise_helper_threads(priority: int) -> int:
    """SCHED_FIFO at ``priority`` for every thread of this process but the caller."""
    return _set_all_threads(os.SCHED_FIFO, max(1, priority), but=threading.get_native_id())


def raise_threads(native_ids: list[int], priority: int) -> int:
    """SCHED_FIFO at ``priority`` for these threads of this process; how many took it.

    For the threads that serve a bus at the process' own priority, above the libraries'
    helpers (one step below, :func:`setup_scheduling`): the virtual drives' reader at 79 waited
    for Zenoh's threads at 79 on two cores, their answer to a request 40 us later than a
    python-can peer's at 80 (bench/bench_drive_echo.py, docs/can.md)."""
    n = 0
    for tid in native_ids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            n += 1
        except OSError:
            pass
    return n


def _set_all_threads(policy: int, priority: int, but: int | None = None) -> int:
    """``policy`` at ``priority`` for every thread of this process (but ``but``); how many."""
    n = 0
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return 0
    for tid in tids:
        if tid == but:
            continue
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
            n += 1
        except OSError:
            pass
    return n


_held_cpu_latency: list[int] = []


def hold_cpu_latency(path: str | None = None) -> None:
    """Ask the kernel (PM QoS) for a 0 us CPU wake-up latency until this process exits.

    An idle CPU otherwise sleeps in an idle state that takes tens of microseconds to leave (a
    virtual CPU halts and the host must schedule it again): every wake-up of the loop, of
    Zenoh's threads and of the peer pays it. The request lives as long as the file stays open,
    and the kernel drops it when the process ends, however it ends. cyclictest makes the same
    request by default, so a wake-up compared with its figure is compared like with like.
    Idempotent; raises ``OSError`` where the file is missing or not writable (root)."""
    if _held_cpu_latency:
        return
    fd = os.open(path or PM_QOS_CPU_LATENCY, os.O_WRONLY | os.O_CLOEXEC)
    try:
        os.write(fd, (0).to_bytes(4, sys.byteorder, signed=True))
    except OSError:
        os.close(fd)
        raise
    _held_cpu_latency.append(fd)


def restore_gc() -> None:
    """The run is over: every thread of the process back to SCHED_OTHER, then the collector
    back on. A service's teardown (the hop log's last flush, Zenoh closed, the interpreter's
    exit with its locked pages: 20 ms and more) at FIFO 80 on its pinned CPU stalled another
    bench run's service there (a plant 46 ms late while a second run's services ended)."""
    if _policy() == os.SCHED_FIFO:
        _set_all_threads(os.SCHED_OTHER, 0)
    gc.enable()
    gc.unfreeze()


def _policy() -> int | None:
    try:
        return os.sched_getscheduler(0)
    except (OSError, AttributeError):
        return None

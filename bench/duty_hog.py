"""A CPU hog of known share: busy ``busy_ms`` of CPU time in every ``every_ms`` of wall time.

    python -m bench.duty_hog --busy-ms 20 --every-ms 40 [--cpu 1] [--fifo 90]
                             [--start-ns T] [--count N]

It spins (never sleeps while busy) until its thread has used ``busy_ms`` of CPU time since the
period began, then sleeps to the next period's start on absolute deadlines, so its share of one
CPU is busy / every whatever else runs beside it, as long as it can get that much CPU in a
period (a period it could not fill is counted as short and printed at the end). ``--cpu`` pins
it, ``--fifo P`` runs it SCHED_FIFO at priority P (root: above the bench's services at 80 it
takes their CPU from them), ``--start-ns`` starts the first period at that CLOCK_MONOTONIC time
(``time.monotonic_ns()``), ``--count`` stops after that many periods (default: until killed).
It prints ``READY`` once set up (before the first period) and ``DONE periods=N short=M`` at the
end. :func:`duty_hog` starts one beside a test and stops it by its PID, as
``bench.kill_matrix.cpu_hog`` does its ``yes`` processes.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def spin(busy_ns: int, every_ns: int, start_ns: int, count: int | None) -> tuple[int, int]:
    """The hog's loop; returns (periods run, periods it could not fill)."""
    periods = short = 0
    t0 = start_ns
    while count is None or periods < count:
        now = time.monotonic_ns()
        if now < t0:
            time.sleep((t0 - now) / 1e9)
        c0 = time.thread_time_ns()
        end = t0 + every_ns
        while time.thread_time_ns() - c0 < busy_ns:
            if time.monotonic_ns() >= end:  # no CPU to be had this period
                short += 1
                break
        periods += 1
        t0 = end
    return periods, short


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--busy-ms", type=float, required=True)
    ap.add_argument("--every-ms", type=float, required=True)
    ap.add_argument("--cpu", type=int, default=None)
    ap.add_argument("--fifo", type=int, default=None)
    ap.add_argument("--start-ns", type=int, default=None)
    ap.add_argument("--count", type=int, default=None)
    a = ap.parse_args(argv)
    if a.cpu is not None:
        os.sched_setaffinity(0, {a.cpu})
    if a.fifo is not None:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.fifo))
    print("READY", flush=True)
    start = a.start_ns if a.start_ns is not None else time.monotonic_ns()
    periods, short = spin(int(a.busy_ms * 1e6), int(a.every_ms * 1e6), start, a.count)
    print(f"DONE periods={periods} short={short}", flush=True)
    return 0


@contextlib.contextmanager
def duty_hog(
    busy_ms: float,
    every_ms: float,
    cpu: int | None = None,
    fifo: int | None = None,
    start_ns: int | None = None,
    count: int | None = None,
) -> Iterator[subprocess.Popen]:
    """One hog (module docstring), started and READY on entry, stopped by its PID on exit."""
    argv = [sys.executable, "-m", "bench.duty_hog", "--busy-ms", str(busy_ms),
            "--every-ms", str(every_ms)]  # fmt: skip
    for flag, value in (("--cpu", cpu), ("--fifo", fifo), ("--start-ns", start_ns),
                        ("--count", count)):  # fmt: skip
        if value is not None:
            argv += [flag, str(value)]
    proc = subprocess.Popen(
        argv, cwd=ROOT, stdout=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        line = proc.stdout.readline() if proc.stdout else ""
        if line.strip() != "READY":
            raise RuntimeError(f"duty hog did not start: {line!r} (exit {proc.poll()})")
        yield proc
    finally:
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)


if __name__ == "__main__":
    raise SystemExit(main())

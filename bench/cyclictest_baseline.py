"""Wake-up lateness baseline from cyclictest (Debian ``rt-tests``) at a given interval.

Prints one JSON object: p50/p99/max wake-up lateness in microseconds, medians over repeats, at
the same policy the controller uses (SCHED_FIFO priority 80 when permitted, else SCHED_OTHER).

    python bench/cyclictest_baseline.py --interval-us 1000 --duration 10 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import tempfile
from pathlib import Path
from typing import Any


def fifo_permitted() -> bool:
    try:
        param = os.sched_getparam(0)
        policy = os.sched_getscheduler(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        os.sched_setscheduler(0, policy, param)
        return True
    except (PermissionError, OSError):
        return False


def percentile_from_histogram(hist: dict[int, int], pct: float) -> float | None:
    total = sum(hist.values())
    if total == 0:
        return None
    target = pct / 100.0 * total
    acc = 0
    for us in sorted(hist):
        acc += hist[us]
        if acc >= target:
            return float(us)
    return float(max(hist))


def run_once(interval_us: int, duration_s: float, fifo: bool, poll: bool = True) -> dict[str, Any]:
    """One cyclictest run; ``poll`` keeps its default CPU latency request of 0 us (the
    services' ``[realtime] idle = "poll"``), else ``--laptop`` drops it (``idle = "os"``)."""
    exe = shutil.which("cyclictest")
    if exe is None:
        raise SystemExit("cyclictest not found: apt-get install rt-tests")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "ct.json"
        argv = [
            exe,
            "-q",
            "-t",
            "1",
            "-i",
            str(interval_us),
            "-D",
            f"{duration_s}s",
            "-h",
            "20000",
            f"--json={out}",
        ]
        if fifo:
            argv += ["-m", "-p", "80"]
        else:
            argv += ["-p", "0"]
        if not poll:
            argv += ["--laptop"]
        subprocess.run(argv, check=True, capture_output=True, timeout=duration_s + 30)
        data = json.loads(out.read_text())
    thread = data["thread"]["0"]
    hist = {int(k): int(v) for k, v in thread["histogram"].items()}
    return {
        "p50_us": percentile_from_histogram(hist, 50),
        "p99_us": percentile_from_histogram(hist, 99),
        "max_us": float(thread["max"]),
        "avg_us": float(thread["avg"]),
        "cycles": int(thread["cycles"]),
    }


def baseline(
    interval_us: int, duration_s: float, repeats: int, poll: bool = True
) -> dict[str, Any]:
    fifo = fifo_permitted()
    runs = [run_once(interval_us, duration_s, fifo, poll) for _ in range(repeats)]
    med = {
        k: statistics.median(r[k] for r in runs if r[k] is not None)
        for k in ("p50_us", "p99_us", "max_us", "avg_us")
    }
    return {
        "tool": "cyclictest",
        "interval_us": interval_us,
        "duration_s": duration_s,
        "policy": "SCHED_FIFO/80" if fifo else "SCHED_OTHER",
        "repeats": repeats,
        "cpu_latency_request": "0 us" if poll else "none (--laptop)",
        "median": med,
        "runs": runs,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--interval-us", type=int, default=1000)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="2 s, 1 repeat")
    a = ap.parse_args()
    if a.quick:
        a.duration, a.repeats = 2.0, 1
    print(json.dumps(baseline(a.interval_us, a.duration, a.repeats), indent=2))


if __name__ == "__main__":
    main()

"""Encode+decode time per message (protocol/messages.py): median and p99 per run, and the median
of those over repeated runs (the machine is shared: repeat, and quote medians).

    python bench/bench_codec.py [--quick] [--runs R] [--n N] [--out FILE]

Each sample times one ``decode(encode(msg))`` with ``time.perf_counter_ns`` (its own overhead,
about 0.1 us, is included and reported as ``timer_overhead_us``). Realistic values: nanosecond
timestamps of ``time.monotonic_ns()`` size and non-round floats.
"""

from __future__ import annotations

import argparse
import gc
import json
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from protocol import messages as m  # noqa: E402


def sample_messages() -> dict[str, m.Message]:
    t = time.monotonic_ns()
    return {
        "State": m.State("robot1", 123_456, t, t + 41_000, 1.2345, -0.5432, 12.345, 0.4987, 0.2013),
        "TorqueCommand": m.TorqueCommand(
            "robot1", 123_455, 123_456, t, t + 50_000, t + 61_000, 3.3, -51.0, "unified", 0
        ),
        "Telemetry": m.Telemetry(
            "robot1", 123_455, t, 0.01, -0.02, 0.003, 1e-3, 0.05, -0.4, 0.2, -0.1, 0.73
        ),
    }


def _one_run(msg: m.Message, n: int) -> dict[str, float]:
    encode, decode, clock = m.encode, m.decode, time.perf_counter_ns
    samples = [0] * n
    gc_was_enabled = gc.isenabled()
    gc.disable()  # a collection inside one sample is noise, not codec cost
    try:
        for i in range(n):
            t0 = clock()
            decode(encode(msg))
            samples[i] = clock() - t0
    finally:
        if gc_was_enabled:
            gc.enable()
    samples.sort()
    return {"median_us": samples[n // 2] / 1000.0, "p99_us": samples[int(0.99 * n)] / 1000.0}


def _timer_overhead_us(n: int = 10_000) -> float:
    clock = time.perf_counter_ns
    samples = []
    for _ in range(n):
        t0 = clock()
        samples.append(clock() - t0)
    return statistics.median(samples) / 1000.0


def run(runs: int = 7, n: int = 20_000) -> dict[str, Any]:
    result: dict[str, Any] = {
        "what": "encode+decode per message, microseconds",
        "runs": runs,
        "n_per_run": n,
        "python": platform.python_version(),
        "timer_overhead_us": _timer_overhead_us(),
        "messages": {},
    }
    for name, msg in sample_messages().items():
        per_run = [_one_run(msg, n) for _ in range(runs)]
        result["messages"][name] = {
            "encoded_bytes": len(m.encode(msg)),
            "median_us": statistics.median(r["median_us"] for r in per_run),
            "p99_us": statistics.median(r["p99_us"] for r in per_run),
            "per_run": per_run,
        }
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--n", type=int, default=20_000, help="samples per run")
    parser.add_argument("--quick", action="store_true", help="runs=3, n=5000")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    args = parser.parse_args(argv)
    if args.quick:
        args.runs, args.n = 3, 5000
    text = json.dumps(run(args.runs, args.n), indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

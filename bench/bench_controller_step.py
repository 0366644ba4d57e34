"""One unified-law update on the real-time (plain float) path: median and p99 per call.

Usage: python bench/bench_controller_step.py [--quick] [--repeats N] [--calls N] [--law NAME]

Each repeat times ``calls`` consecutive updates with time.perf_counter_ns around every call,
over a slowly moving state so the branches vary; the JSON line reports the median over repeats
of each repeat's median and p99 (microseconds) against the 30 us p99 budget (3% of 1 ms).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time

import _here  # noqa: F401  (this checkout first on sys.path)

from controller_service.laws.base import DesignContext, RobotState
from controller_service.references import Circle
from controller_service.registry import build_controller

BUDGET_P99_US = 30.0


def one_repeat(law: str, calls: int) -> tuple[float, float]:
    controller = build_controller({"law": law}, DesignContext())
    reference = Circle()
    memory = controller.initial_memory()
    refs = [reference.sample(k * 1e-3) for k in range(calls)]
    states = [
        RobotState(0.3 * math.sin(k * 1e-3), -1.0 + 1e-5 * k, 0.1, 0.4, 0.2 * math.cos(k * 1e-2))
        for k in range(calls)
    ]
    samples = [0] * calls
    clock = time.perf_counter_ns
    update = controller.update
    for k in range(calls):
        start = clock()
        _, memory = update(k * 1e-3, 1e-3, states[k], refs[k], memory)
        samples[k] = clock() - start
    samples.sort()
    return samples[calls // 2] / 1e3, samples[min(calls - 1, int(0.99 * calls))] / 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 repeats of 2,000 calls")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--calls", type=int, default=10_000)
    parser.add_argument("--law", default="unified")
    args = parser.parse_args()
    repeats, calls = (5, 2_000) if args.quick else (args.repeats, args.calls)
    one_repeat(args.law, 500)  # warm-up
    results = [one_repeat(args.law, calls) for _ in range(repeats)]
    p50 = statistics.median(r[0] for r in results)
    p99 = statistics.median(r[1] for r in results)
    print(
        json.dumps(
            {
                "bench": "controller_step",
                "law": args.law,
                "path": "float",
                "repeats": repeats,
                "calls_per_repeat": calls,
                "median_us": round(p50, 3),
                "p99_us": round(p99, 3),
                "worst_repeat_p99_us": round(max(r[1] for r in results), 3),
                "budget_p99_us": BUDGET_P99_US,
                "within_budget": p99 <= BUDGET_P99_US,
                "python": platform.python_version(),
                "machine": platform.machine(),
            }
        )
    )


if __name__ == "__main__":
    main()

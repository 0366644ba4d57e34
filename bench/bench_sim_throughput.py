"""Closed-loop robot-steps per second of the offline simulator .

One robot-step = one control period of one loop at Ts = 1 ms with the default plant integration
(10 RK4 steps of 0.1 ms) and the unified law (Table 1) on the paper's tracking scenario. Measures
the batch path (``simulate_batch``) for N = 1, 100, 10,000 and the single-run float path
(``simulate``) in the same run; each figure is the median of ``--repeats`` runs. Prints JSON.
The batch path runs on one thread (``"threads": 1``; splitting N over threads was slower, the
numpy operations at N = 10,000 being too short to amortize the GIL hand-overs). ``"source"``
is the tree measured: this file's checkout, ahead of any editable install on sys.path.

    python bench/bench_sim_throughput.py            # full
    python bench/bench_sim_throughput.py --quick    # fewer periods and repeats

Targets: >= 2,000,000 robot-steps/s at N = 10,000 and >= 20x the single-run path.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

# Measure the checkout this file belongs to, not whichever tree an editable install points at.
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hil.scenario import build_loop, load_scenario  # noqa: E402
from hil.sim import simulate, simulate_batch  # noqa: E402

SCENARIO = ROOT / "hil" / "scenarios" / "paper_tracking.toml"


def _rate(fn, robots: int, periods: int, repeats: int) -> dict[str, float]:  # type: ignore[no-untyped-def]
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        rates.append(robots * periods / (time.perf_counter() - start))
    return {
        "median_robot_steps_per_s": statistics.median(rates),
        "min": min(rates),
        "max": max(rates),
        "repeats": repeats,
        "periods": periods,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer periods and repeats")
    parser.add_argument("--repeats", type=int, default=None)
    args = parser.parse_args()
    repeats = args.repeats or (3 if args.quick else 5)
    base = load_scenario(SCENARIO)
    loop = build_loop(base)
    results: dict[str, object] = {}
    # Periods per measurement: enough for a stable figure, scaled down for large N.
    plan = {1: 2000, 100: 1000, 10000: 100} if not args.quick else {1: 500, 100: 200, 10000: 30}
    for n, periods in plan.items():
        sc = base.with_overrides(duration=periods * base.timing.ts)
        results[f"batch_N{n}"] = _rate(
            lambda sc=sc, n=n: simulate_batch(sc, n, loop=loop), n, periods, repeats
        )
    single_periods = 500 if args.quick else 2000
    sc = base.with_overrides(duration=single_periods * base.timing.ts)
    results["single_float"] = _rate(lambda: simulate(sc, loop=loop), 1, single_periods, repeats)
    single = results["single_float"]["median_robot_steps_per_s"]  # type: ignore[index]
    big = results["batch_N10000"]["median_robot_steps_per_s"]  # type: ignore[index]
    out = {
        "benchmark": "closed-loop robot-steps per second, Ts = 1 ms, h = 0.1 ms, unified law",
        "source": str(Path(simulate_batch.__code__.co_filename).resolve().parents[2]),
        "threads": 1,
        "machine": {
            "cpu_count": os.cpu_count(),
            "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(),
            "load_avg_1min": os.getloadavg()[0],
        },
        "results": results,
        "batch_N10000_over_single": big / single,
        "targets": {"batch_N10000_min": 2_000_000, "ratio_min": 20},
        "targets_met": {"batch_N10000": big >= 2_000_000, "ratio": big / single >= 20},
        "quick": args.quick,
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()

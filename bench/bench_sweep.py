"""Sweep throughput in robot-steps per second, batch path against the single-run path.

A robot-step is one control period of one closed loop (Ts = 1 ms, default plant integration
Ts/10 with RK4). The batch figures run 10,000 loops at once with ``hil.sim.simulate_batch``:
on the compiled kernel (hil/sim/compiled.py, compiled by a warm-up call first, as a sweep
compiles it once) and on the numpy path (``HIL_NO_COMPILED=1``, the reference); the sweep
figure runs them through ``hil sweep``'s runner (one Ts group, 10,000 seeds); the single
figure runs one loop with ``hil.sim.simulate``, in the same process and run, so the ratios are
meaningful on a noisy machine. Medians of repeats.

    python bench/bench_sweep.py            # 10,000 loops x 0.2 s, 3 repeats
    python bench/bench_sweep.py --quick    # 1,000 loops x 0.05 s, 1 repeat
Targets: >= 10,000,000 robot-steps/s on 2 cores and >= 300x the single-run path (the figures
and what limits them: docs/performance.md). The single-run path is the baseline measured in the
same run; the machine (cores, load average, numpy) is printed with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import _here  # noqa: F401  (this checkout first on sys.path)
import numpy as np

from hil.scenario import loads_scenario
from hil.sim import compiled, simulate, simulate_batch
from hil.sweep.grid import make_grid
from hil.sweep.runner import run_sweep, scenario_at
from tests.scenario_text import TABLE1, circle

SCENARIO = circle(controller=TABLE1, timing={"ts": 0.001})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--loops", type=int, default=None)
    ap.add_argument("--duration", type=float, default=None, help="seconds per loop")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    a = ap.parse_args()
    loops = a.loops or (1_000 if a.quick else 10_000)
    duration = a.duration or (0.05 if a.quick else 0.2)
    repeats = a.repeats or (1 if a.quick else 3)
    base = loads_scenario(SCENARIO, Path.cwd())
    sc = scenario_at(base, 0.001, duration)
    single_sc = scenario_at(base, 0.001, max(duration, 1.0))
    steps = round(duration / 0.001)

    compiled.MIN_WORK = 0  # the warm-up below compiles the kernel, as in a long sweep
    t0 = time.perf_counter()
    simulate_batch(sc, 2)
    compile_s = time.perf_counter() - t0
    raw, numpy_raw, sweep, single = [], [], [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        simulate_batch(sc, loops)
        raw.append(loops * steps / (time.perf_counter() - t0))
        os.environ["HIL_NO_COMPILED"] = "1"
        t0 = time.perf_counter()
        simulate_batch(sc, loops)
        numpy_raw.append(loops * steps / (time.perf_counter() - t0))
        del os.environ["HIL_NO_COMPILED"]
        t0 = time.perf_counter()
        outcome, _ = run_sweep(base, make_grid([0.001], [0.0], [0.0], loops), duration)
        sweep.append(outcome.robot_steps / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        r = simulate(single_sc)
        single.append(len(r.trace) / (time.perf_counter() - t0))
    out = {
        "loops": loops,
        "duration_s": duration,
        "repeats": repeats,
        "batch_robot_steps_per_s": statistics.median(raw),
        "numpy_batch_robot_steps_per_s": statistics.median(numpy_raw),
        "sweep_runner_robot_steps_per_s": statistics.median(sweep),
        "single_robot_steps_per_s": statistics.median(single),
        "kernel_compile_s": compile_s,
        "cores": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
        "python": platform.python_version(),
        "numpy": np.__version__,
    }
    out["ratio_batch_to_single"] = out["batch_robot_steps_per_s"] / out["single_robot_steps_per_s"]
    out["ratio_numpy_batch_to_single"] = (
        out["numpy_batch_robot_steps_per_s"] / out["single_robot_steps_per_s"]
    )
    out["ratio_sweep_to_single"] = (
        out["sweep_runner_robot_steps_per_s"] / out["single_robot_steps_per_s"]
    )
    for k, v in out.items():
        print(f"{k:32s} {v:,.6g}" if isinstance(v, float) else f"{k:32s} {v}")
    print(
        "targets: >= 10,000,000 robot-steps/s:",
        "met" if out["batch_robot_steps_per_s"] >= 1e7 else "NOT met",
        "| >= 300x single:",
        "met" if out["ratio_batch_to_single"] >= 300 else "NOT met",
    )
    if a.json:
        a.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()

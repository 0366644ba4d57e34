"""The speed-up of a sweep's chunks on 2 workers over 1 (hil.sweep.chunks).

The same grid and chunks (the paper's tracking circle; Ts 2 and 5 ms x 4 delays x 2 jitters x S
seeds, 10 s a loop, chunks of 64: 128 points a Ts in 2 chunks) run in this process (1 worker),
on a local process pool of 2 and on a Dask LocalCluster of 2 worker processes on loopback;
each time is the best of the repeats, and the rows are checked equal to the in-process ones bit
for bit. A process pool's and a cluster's start-up count in their time (a sweep pays them once).

    python bench/bench_sweep_cluster.py            # 16 seeds, 2 repeats
    python bench/bench_sweep_cluster.py --quick    # 8 seeds, 2 s a loop, 1 repeat
Prints one JSON object (also written with --out FILE).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import _here  # noqa: F401  (this checkout first on sys.path)

from hil.bench.defaults import PAPER_TRACKING_TOML
from hil.scenario import loads_scenario
from hil.sweep.chunks import chunks_of, run_chunked
from hil.sweep.executors import DaskCluster, InProcess, ProcessPool
from hil.sweep.grid import make_grid


def _timed(run: Any) -> tuple[float, Any]:
    t = time.perf_counter()
    out = run()
    return time.perf_counter() - t, out


def one(kind: str, sc: Any, grid: Any, duration: float, chunk: int) -> tuple[float, list]:
    """Seconds and rows of the sweep on ``kind``, executor start-up included."""

    def go() -> list:
        if kind == "in-process":
            return run_chunked(sc, grid, duration, InProcess(), chunk)[0].rows
        if kind == "pool-2":
            pool = ProcessPool(2)
            try:
                return run_chunked(sc, grid, duration, pool, chunk)[0].rows
            finally:
                pool.close()
        from distributed import Client, LocalCluster

        with (
            LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                         dashboard_address=None) as cluster,
            Client(cluster) as client,
        ):  # fmt: skip
            return run_chunked(sc, grid, duration, DaskCluster(client=client), chunk)[0].rows

    return _timed(go)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--seeds", type=int, default=16)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--chunk-size", type=int, default=64)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    if a.quick:
        a.seeds, a.duration, a.repeats = 8, 2.0, 1
    sc = loads_scenario(PAPER_TRACKING_TOML)
    grid = make_grid((0.002, 0.005), (0.0, 0.002, 0.01, 0.02), (0.0, 0.001), a.seeds)
    times: dict[str, float] = {}
    rows: dict[str, str] = {}
    for _ in range(a.repeats):
        for kind in ("in-process", "pool-2", "dask-2"):
            secs, got = one(kind, sc, grid, a.duration, a.chunk_size)
            times[kind] = min(times.get(kind, secs), secs)
            rows[kind] = json.dumps(got, default=repr)
    base = times["in-process"]
    result = {
        "points": len(grid),
        "chunks": len(chunks_of(sc, grid, a.duration, a.chunk_size)),
        "loop_s": a.duration,
        "seconds": times,
        "speedup_2_over_1": {k: base / v for k, v in times.items() if k != "in-process"},
        "rows_identical": {k: rows[k] == rows["in-process"] for k in rows},
    }
    text = json.dumps(result, indent=2)
    print(text)
    if a.out:
        a.out.write_text(text + "\n")
    return 0 if all(result["rows_identical"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())

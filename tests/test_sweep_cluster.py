"""Sweeps in chunks on any executor (hil.sweep.chunks, hil.sweep.executors): the same chunks give
the same rows bit for bit in this process, on a local process pool and on a Dask LocalCluster of
two worker processes (loopback only), whose processes are gone once it closes; progress counts
chunks; the command line refuses what it cannot run."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import pytest

from hil.bench.defaults import PAPER_TRACKING_TOML
from hil.errors import BadInputError
from hil.scenario import loads_scenario
from hil.sweep.chunks import chunks_of, run_chunked
from hil.sweep.executors import DaskCluster, ProcessPool, executor_for
from hil.sweep.grid import make_grid

# 2 Ts x 2 delays x 2 jitters x 2 seeds: 16 points, 8 a group; seeds make the jitter differ.
GRID = make_grid((0.01, 0.02), (0.0, 0.01), (0.0, 0.002), 2)
DURATION = 2.0


def _scenario():
    return loads_scenario(PAPER_TRACKING_TOML)


def _exact(rows: list[dict]) -> str:
    """The rows as text that keeps every bit of every float (NaN equals NaN here)."""
    return json.dumps(rows, default=repr, allow_nan=True)


def test_a_local_dask_cluster_gives_the_in_process_rows_bit_for_bit():
    from distributed import Client, LocalCluster

    sc = _scenario()
    here, resolved_here = run_chunked(sc, GRID, DURATION, chunk_size=3)
    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                     dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):  # fmt: skip
        pids = client.run(os.getpid)
        addresses = [cluster.scheduler_address, *pids]
        assert all(a.startswith("tcp://127.0.0.1:") for a in addresses), addresses
        assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()
        there, resolved_there = run_chunked(
            sc, GRID, DURATION, executor=DaskCluster(client=client), chunk_size=3
        )
    assert len(here.rows) == len(GRID) and _exact(here.rows) == _exact(there.rows)
    assert here.groups_done == there.groups_done == 2
    assert here.robot_steps == there.robot_steps > 0
    # The resolved scenario is the same (its provenance says when and where it was resolved).
    assert {k: v for k, v in resolved_here.items() if k != "provenance"} == {
        k: v for k, v in resolved_there.items() if k != "provenance"
    }
    # The seeds made the points differ: identical rows are not identical points.
    assert len({r["final_position_error"] for r in here.rows}) > 4
    deadline = time.monotonic() + 30
    while any(_alive(p) for p in pids.values()) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(_alive(p) for p in pids.values()), "a Dask worker outlived its cluster"


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as f:
            return "zombie" not in f.read()
    except OSError:
        return False


def test_a_process_pool_gives_the_same_rows_and_progress_counts_chunks():
    sc = _scenario()
    seen: list[tuple[int, int]] = []
    pool = ProcessPool(2)
    try:
        pooled, _ = run_chunked(sc, GRID, DURATION, executor=pool, chunk_size=3,
                                progress=lambda d, n: seen.append((d, n)))  # fmt: skip
    finally:
        pool.close()
    here, _ = run_chunked(sc, GRID, DURATION, chunk_size=3)
    assert _exact(pooled.rows) == _exact(here.rows)
    n = len(chunks_of(sc, GRID, DURATION, 3))
    assert n == 6 and seen == [(k, n) for k in range(1, n + 1)]  # 8 points a Ts: 3 + 3 + 2


def test_another_chunking_changes_at_most_the_last_bits():
    """numpy's vectorized math depends on how many robots share a batch, so another chunk size
    may change the last bits of a float (never a flag or a count); the chunk size is part of
    the sweep's definition (sweep.json ``chunk_size``)."""
    sc = _scenario()
    a, _ = run_chunked(sc, GRID, DURATION, chunk_size=3)
    b, _ = run_chunked(sc, GRID, DURATION, chunk_size=8)
    for ra, rb in zip(a.rows, b.rows, strict=True):
        assert ra.keys() == rb.keys()
        for k, va in ra.items():
            vb = rb[k]
            if isinstance(va, float) and not isinstance(va, bool):
                assert math.isclose(va, vb, rel_tol=1e-12, abs_tol=1e-15), (k, va, vb)
            else:
                assert va == vb, (k, va, vb)


def test_the_command_line_refuses_what_it_cannot_run():
    with pytest.raises(BadInputError, match="exclude each other"):
        executor_for(2, "tcp://127.0.0.1:8786")
    with pytest.raises(BadInputError, match="tcp://HOST:PORT"):
        executor_for(None, "127.0.0.1:8786")
    with pytest.raises(BadInputError, match="--workers"):
        executor_for(0, None)
    assert executor_for(None, None).name == "in-process"


def test_hil_sweep_on_workers_or_a_scheduler_writes_what_the_in_process_sweep_writes(tmp_path):
    base = [sys.executable, "-m", "hil", "sweep", "paper_tracking", "--ts", "0.01,0.02",
            "--delay", "0,0.01", "--jitter", "0,0.002", "--seeds", "2", "--duration", "2",
            "--chunk-size", "3"]  # fmt: skip
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:  # fmt: skip
        address = cluster.scheduler_address
        for name, extra in (("here", []), ("pool", ["--workers", "2"]),
                            ("dask", ["--scheduler", address])):  # fmt: skip
            proc = subprocess.run([*base, "--out", str(tmp_path / name), *extra],
                                  capture_output=True, text=True, timeout=300)  # fmt: skip
            assert proc.returncode == 0, proc.stderr[-2000:]
    here = (tmp_path / "here" / "sweep.csv").read_text()
    for name, executor in (("pool", "2 local processes"), ("dask", f"Dask cluster at {address}")):
        assert here == (tmp_path / name / "sweep.csv").read_text(), name
        meta = json.loads((tmp_path / name / "sweep.json").read_text())
        assert meta["executor"] == executor and meta["chunks"] == 6

"""A sweep split into chunks that run on any executor (:mod:`hil.sweep.executors`): each Ts
group of the grid (:meth:`SweepGrid.by_ts`, longest Ts first) cut into slices of at most
``chunk_size`` points, numbered in that order, each one :func:`hil.sweep.runner.simulate_points`.

Same results whatever the executor and the chunking, bit for bit: each point carries its own
seed (the scenario's plus the seed's index), never one drawn from a chunk's or a worker's state;
the batch path computes each robot on its own; a group keeps its traces (for the quasi-sliding
band) by the group's size, not the chunk's; the results are put back in the grid's order.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hil.provenance import Toml
from hil.scenario import Scenario
from hil.sweep.executors import InProcess
from hil.sweep.grid import SweepGrid, SweepPoint, SweepRow
from hil.sweep.runner import RECORD_LIMIT, SweepOutcome, scenario_at, simulate_points

# Points per chunk: the batch path's cost per robot falls with the batch's size (numpy's
# per-step overhead is shared), 128 points in chunks of 8 took 6x as long as in one chunk;
# 64 keeps most of that and still splits a large group between workers.
DEFAULT_CHUNK = 64


@dataclass(frozen=True)
class Chunk:
    """One unit of work: ``points`` (one Ts) of the sweep, numbered ``index``."""

    index: int
    scenario: Scenario
    ts: float
    points: tuple[SweepPoint, ...]
    record: bool  # keep traces: the whole group has at most RECORD_LIMIT points


@dataclass
class ChunkResult:
    index: int
    rows: list[SweepRow] = field(default_factory=list)
    robot_steps: int = 0
    interrupted: bool = False
    resolved: Toml = field(default_factory=dict)


def chunks_of(
    scenario: Scenario, grid: SweepGrid, duration: float, chunk_size: int = DEFAULT_CHUNK
) -> list[Chunk]:
    """The sweep's chunks in order."""
    if chunk_size < 1:
        raise ValueError("chunk_size must be >= 1")
    out: list[Chunk] = []
    for ts, points in grid.by_ts(scenario.timing.seed):
        sc = scenario_at(scenario, ts, duration)
        record = len(points) <= RECORD_LIMIT
        for at in range(0, len(points), chunk_size):
            out.append(Chunk(len(out), sc, ts, tuple(points[at : at + chunk_size]), record))
    return out


def run_chunk(chunk: Chunk) -> ChunkResult:
    """Simulate one chunk and build its rows (a top-level function: pickled to workers)."""
    rows, result = simulate_points(chunk.scenario, chunk.points, chunk.record)
    steps = len(chunk.points) * int(result.summaries[0]["samples"])
    return ChunkResult(chunk.index, rows, steps, bool(result.interrupted), result.resolved)


def run_chunked(
    scenario: Scenario,
    grid: SweepGrid,
    duration: float,
    executor: Any = None,
    chunk_size: int = DEFAULT_CHUNK,
    progress: Callable[[int, int], None] | None = None,
    on_chunk: Callable[[list[SweepRow]], None] | None = None,
) -> tuple[SweepOutcome, Toml]:
    """The sweep on ``executor`` (default: in this process), as :func:`run_sweep` returns it:
    the rows in the grid's order (Ts groups longest first); ``groups_done`` counts the Ts
    groups whose every chunk finished; ``progress(chunks done, chunks in all)``. Ctrl-C keeps
    the chunks done."""
    chunks = chunks_of(scenario, grid, duration, chunk_size)
    done: list[ChunkResult] = []
    outcome = SweepOutcome()
    try:
        for res in (executor or InProcess()).map(run_chunk, chunks):
            done.append(res)
            outcome.robot_steps += res.robot_steps
            if progress is not None:
                progress(len(done), len(chunks))
            if on_chunk is not None:
                on_chunk([row for r in done for row in r.rows])
            if res.interrupted:
                outcome.interrupted = True
                break
    except KeyboardInterrupt:
        outcome.interrupted = True
    done.sort(key=lambda r: r.index)
    outcome.rows = [row for r in done for row in r.rows]
    finished = {r.index for r in done if not r.interrupted}
    unfinished = {c.ts for c in chunks if c.index not in finished}
    outcome.groups_done = len({c.ts for c in chunks} - unfinished)
    return outcome, (done[0].resolved if done else {})

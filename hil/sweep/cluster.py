"""``hil sweep --workers N`` / ``--scheduler tcp://HOST:PORT`` / ``--chunk-size K``: the sweep
in chunks on an executor (:mod:`hil.sweep.chunks`, :mod:`hil.sweep.executors`) under a progress
bar counting chunks done."""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypedDict

from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from hil import options
from hil.provenance import Toml
from hil.sweep.chunks import DEFAULT_CHUNK, chunks_of, run_chunked
from hil.sweep.executors import executor_for
from hil.sweep.outputs import write_csv

CHUNK_MAX = 1_000_000


def wanted(workers: int | None, scheduler: str | None, chunk_size: int | None) -> bool:
    """Whether the command line asks for the chunked path."""
    return workers is not None or scheduler is not None or chunk_size is not None


class ExecutorFacts(TypedDict):
    """Where a sweep ran beyond this process (sweep.json)."""

    executor: str
    chunks: int
    chunk_size: int


def open_executor(workers: int | None, scheduler: str | None, chunk_size: int | None) -> Any:
    """The executor, every option checked first (BadInputError: exit 2, before any folder)."""
    if chunk_size is not None:
        options.integer("--chunk-size", chunk_size, 1, CHUNK_MAX)
    return executor_for(workers, scheduler)


def run_with_executor(
    scenario: Any, grid: Any, loop_s: float, target: Path, executor: Any, chunk_size: int | None
) -> tuple[Any, Toml, ExecutorFacts]:
    """(outcome, resolved, what to add to sweep.json's meta); the executor closed after."""
    size = chunk_size or DEFAULT_CHUNK
    n = len(chunks_of(scenario, grid, loop_s, size))
    try:
        with Progress(
            TextColumn("[bold]sweep[/bold] " + executor.name),
            BarColumn(),
            TextColumn("{task.completed:,.0f}/{task.total:,.0f} chunks"),
            TimeRemainingColumn(),
        ) as bar:
            task = bar.add_task("chunks", total=n)
            outcome, resolved = run_chunked(
                scenario, grid, loop_s, executor, size,
                progress=lambda done, _total: bar.update(task, completed=done),
                on_chunk=lambda rows: write_csv(target / "sweep.csv", rows),
            )  # fmt: skip
    finally:
        executor.close()
    return outcome, resolved, ExecutorFacts(executor=executor.name, chunks=n, chunk_size=size)

"""Where the chunks of a sweep run: anything with ``map(fn, items)`` yielding ``fn(item)`` in order.

- :class:`InProcess`: this process, one chunk after another (the default);
- :class:`ProcessPool`: ``--workers N`` local processes (``concurrent.futures``, spawned, so
  nothing of this process's state leaks into them);
- :class:`DaskCluster`: ``--scheduler tcp://HOST:PORT``, a Dask distributed cluster's scheduler
  (the optional extra ``pip install hil-smc-bench[cluster]``); every worker needs this package
  installed at the same version, and the scenario's files (a reference CSV, a replayed run's
  latencies) at the same paths.

The chunk function and its arguments are pickled for the pool and the cluster: top-level
functions and plain dataclasses only.
"""

from __future__ import annotations

import multiprocessing
import re
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from hil import options
from hil.errors import BadInputError

try:  # the optional extra [cluster]: without it, only --scheduler is refused
    from distributed import Client
except ImportError:
    Client = None

WORKERS_MAX = 1024
_SCHEDULER_RE = re.compile(r"tcp://[A-Za-z0-9.\-\[\]:]+:[0-9]{1,5}")


class InProcess:
    name = "in-process"

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        return map(fn, items)

    def close(self) -> None:
        pass


class ProcessPool:
    def __init__(self, workers: int) -> None:
        self.name = f"{workers} local processes"
        ctx = multiprocessing.get_context("spawn")
        self._pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx)

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        return self._pool.map(fn, items)

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


class DaskCluster:
    """A Dask distributed cluster: the scheduler at ``address``, or a given ``client``."""

    def __init__(self, address: str | None = None, client: Any = None) -> None:
        self._owned = client is None
        if client is None:
            if Client is None:
                raise BadInputError(
                    "--scheduler needs Dask distributed: pip install 'hil-smc-bench[cluster]'"
                )
            try:
                client = Client(address, timeout=30)
            except OSError as exc:
                raise BadInputError(f"--scheduler {address}: {exc}") from exc
        self._client = client
        self.name = f"Dask cluster at {client.scheduler.address}"
        self._futures: list[Any] = []

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        # pure=False: a chunk is never served from another call's cache.
        self._futures = self._client.map(fn, list(items), pure=False)
        for future in self._futures:
            yield future.result()

    def close(self) -> None:
        if self._futures:
            self._client.cancel(self._futures)
        if self._owned:
            self._client.close()


def executor_for(
    workers: int | None, scheduler: str | None
) -> InProcess | ProcessPool | DaskCluster:
    """The executor the command line asks for (BadInputError for a bad or double choice)."""
    if workers is not None and scheduler is not None:
        raise BadInputError("--workers and --scheduler exclude each other")
    if scheduler is not None:
        if _SCHEDULER_RE.fullmatch(scheduler) is None:
            raise BadInputError(f"--scheduler must be tcp://HOST:PORT, got {scheduler!r}")
        return DaskCluster(scheduler)
    if workers is not None:
        options.integer("--workers", workers, 1, WORKERS_MAX)
        return InProcess() if workers == 1 else ProcessPool(workers)
    return InProcess()

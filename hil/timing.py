"""Timing figures of a run: exact percentile summaries in microseconds.

Every figure a run records (wake-up lateness, period jitter, compute time, sample-to-apply
latency per path, transport hops) is a list of durations in nanoseconds taken from
``time.monotonic_ns()`` stamps on one host. :func:`summarize` turns one such list into the
contract's percentile object: ``p50_us``, ``p90_us``, ``p99_us``, ``p999_us``, ``max_us`` plus
``count`` and ``mean_us``. Every percentile is one of the measured values (numpy's
``inverted_cdf``, :func:`hil.measure.stats.summarize_ns`, the one definition the run's
summary.json uses), so none can exceed ``max_us``.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from hil.measure.stats import summarize_ns


def summarize(values_ns: Iterable[int | float]) -> dict[str, Any]:
    """Percentile summary (microseconds) of durations given in nanoseconds; exact."""
    return summarize_ns(list(values_ns))


def diffs(stamps_ns: Iterable[int]) -> list[int]:
    """Successive differences of a sequence of time stamps (periods between events)."""
    out: list[int] = []
    prev: int | None = None
    for s in stamps_ns:
        if prev is not None:
            out.append(s - prev)
        prev = s
    return out


def period_jitter(stamps_ns: Iterable[int], period_ns: int) -> list[int]:
    """|actual period - nominal period| of successive wake-ups, in nanoseconds."""
    return [abs(d - period_ns) for d in diffs(stamps_ns)]

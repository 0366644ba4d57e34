"""Timing figures of a run: HDR-histogram percentile summaries in microseconds.

Every figure a run records (wake-up lateness, period jitter, compute time, sample-to-apply
latency per path, transport hops) is a list of durations in nanoseconds taken from
``time.monotonic_ns()`` stamps on one host. :func:`summarize` turns one such list into the
contract's percentile object: ``p50_us``, ``p90_us``, ``p99_us``, ``p999_us``, ``max_us`` plus
``count`` (and ``mean_us``). An HDR histogram with 3 significant digits keeps the error of every
percentile below 0.1 % at any scale, from microseconds to seconds of outliers.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from hdrh.histogram import HdrHistogram

#: Largest duration the histograms can hold: one minute, in nanoseconds.
MAX_TRACKABLE_NS = 60 * 1_000_000_000
PERCENTILES = (("p50_us", 50.0), ("p90_us", 90.0), ("p99_us", 99.0), ("p999_us", 99.9))


class LatencyHistogram:
    """An HDR histogram of non-negative durations in nanoseconds, summarized in microseconds.

    Negative values (a clock read out of order across processes cannot happen with one
    monotonic clock, but a bad message could carry one) are counted in ``negative`` and clamped
    to zero rather than dropped, so a reader sees that something was off.
    """

    def __init__(self) -> None:
        self._hist = HdrHistogram(1, MAX_TRACKABLE_NS, 3)
        self.count = 0
        self.negative = 0
        self.overflow = 0
        self._sum_ns = 0
        self._max_ns = 0

    def record(self, value_ns: int | float) -> None:
        v = int(value_ns)
        if v < 0:
            self.negative += 1
            v = 0
        if v > MAX_TRACKABLE_NS:
            self.overflow += 1
            v = MAX_TRACKABLE_NS
        # HdrHistogram's lowest trackable value is 1 ns; a 0 ns duration is recorded as 0.
        self._hist.record_value(v)
        self.count += 1
        self._sum_ns += v
        if v > self._max_ns:
            self._max_ns = v

    def record_all(self, values_ns: Iterable[int | float]) -> LatencyHistogram:
        for v in values_ns:
            self.record(v)
        return self

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"count": self.count}
        if self.count == 0:
            for name, _ in PERCENTILES:
                out[name] = None
            out["max_us"] = None
            out["mean_us"] = None
            return out
        for name, pct in PERCENTILES:
            out[name] = self._hist.get_value_at_percentile(pct) / 1000.0
        # The exact maximum, not the histogram's bucket edge: the worst case is the point.
        out["max_us"] = self._max_ns / 1000.0
        out["mean_us"] = self._sum_ns / self.count / 1000.0
        if self.negative:
            out["negative"] = self.negative
        if self.overflow:
            out["overflow"] = self.overflow
        return out


def summarize(values_ns: Iterable[int | float]) -> dict[str, Any]:
    """Percentile summary (microseconds) of durations given in nanoseconds."""
    return LatencyHistogram().record_all(values_ns).summary()


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

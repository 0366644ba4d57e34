"""Exact percentile summaries of durations (nanoseconds in, microseconds out): every
percentile is one of the measured values (:func:`hil.analysis.trace_metrics.percentile`'s
definition), so none can exceed the maximum and nothing is rounded to a histogram bucket."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from hil.folder.records import Percentiles

PERCENTILES = (("p50_us", 50.0), ("p90_us", 90.0), ("p99_us", 99.0), ("p999_us", 99.9))


def exact_percentile(values: Any, q: float) -> float | None:
    """The ``q``-th percentile as every percentile of the bench: one of the values (numpy's
    ``inverted_cdf``: the smallest value with at least q % of them at or below it); None for
    no values."""
    v = np.asarray(values, dtype=float).ravel()
    return float(np.percentile(v, q, method="inverted_cdf")) if v.size else None


def empty_summary() -> Percentiles:
    none = dict.fromkeys([name for name, _ in PERCENTILES] + ["max_us", "mean_us"])
    return cast(Percentiles, {"count": 0, **none})


def summarize_ns(values_ns: Any) -> Percentiles:
    """count, p50/p90/p99/p999/max/mean in microseconds of durations given in nanoseconds."""
    v = np.asarray(values_ns, dtype=np.int64).ravel()
    if v.size == 0:
        return empty_summary()
    qs = np.percentile(v, [q for _, q in PERCENTILES], method="inverted_cdf")
    quantiles = {name: q for (name, _), q in zip(PERCENTILES, qs, strict=True)}
    out = summary_from_quantiles(v.size, quantiles, v.max(), v.mean())
    neg = int((v < 0).sum())
    if neg:
        out["negative"] = neg
    return out


def summary_from_quantiles(
    count: int, quantile_ns: Mapping[str, float], max_ns: int, mean_ns: float
) -> Percentiles:
    """The same object from percentiles computed elsewhere (the command age's; ``count`` > 0)."""
    out: Percentiles = {"count": int(count)}
    out.update({name: int(quantile_ns[name]) / 1000.0 for name, _ in PERCENTILES})
    out["max_us"] = int(max_ns) / 1000.0
    out["mean_us"] = float(mean_ns) / 1000.0
    return out


def within(x: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """The mask of ``x`` inside [lo, hi]."""
    return (x >= lo) & (x <= hi)


def lookup(
    keys: np.ndarray, values: np.ndarray, query: np.ndarray, missing: int = -1, ordered=False
):
    """values[keys == q] for each q (keys distinct), ``missing`` where absent; vectorised.
    ``ordered``: the keys are already ascending (no sort)."""
    out = np.full(query.size, missing, dtype=values.dtype if values.size else np.int64)
    if keys.size == 0:
        return out, np.zeros(query.size, bool)
    if not ordered:
        order = np.argsort(keys, kind="stable")
        keys, values = keys[order], values[order]
    pos = np.clip(np.searchsorted(keys, query), 0, keys.size - 1)
    found = keys[pos] == query
    out[found] = values[pos[found]]
    return out, found

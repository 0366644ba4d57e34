"""Timing summaries (hil.analysis.measure.stats): exact percentiles in µs from nanosecond
samples."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.analysis.measure.stats import summarize_ns as summarize


def test_summary_has_the_contract_keys_in_microseconds():
    s = summarize([1_000, 2_000, 3_000, 4_000_000])
    assert set(s) >= {"p50_us", "p90_us", "p99_us", "p999_us", "max_us", "count"}
    assert s["count"] == 4
    assert s["max_us"] == 4000.0  # exact, not a bucket edge
    assert s["p50_us"] == 2.0  # exact: one of the samples


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(min_value=0, max_value=10_000_000_000), min_size=1, max_size=300))
def test_percentiles_are_exact_samples_never_above_the_max(values):
    s = summarize(values)
    arr = np.sort(np.array(values, dtype=np.int64))
    for key, pct in (("p50_us", 50), ("p90_us", 90), ("p99_us", 99), ("p999_us", 99.9)):
        # the smallest sample with at least pct % of the samples at or below it
        rank = max(1, int(np.ceil(pct / 100.0 * len(arr))))
        assert s[key] == arr[rank - 1] / 1000.0, (key, s[key], arr[rank - 1])
        assert s[key] <= s["max_us"]
    assert s["max_us"] == arr[-1] / 1000.0


def test_negative_durations_are_counted_not_hidden():
    s = summarize([-5, 10])
    assert s["negative"] == 1
    assert s["count"] == 2


def test_empty_summary_is_explicit():
    s = summarize([])
    assert s["count"] == 0 and s["p99_us"] is None

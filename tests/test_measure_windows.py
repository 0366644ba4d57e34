"""Known answers for hil.analysis.measure.windows: figures per window (a soak's minutes) with
nothing clipped at the windows' edges.

The reference for every percentile is brute force: the age at every plant step of the
segments a window owns, enumerated one by one, and numpy's ``inverted_cdf`` over them."""

from __future__ import annotations

import numpy as np
import pytest

from hil.analysis.measure.age import AgeSegments, age_summary
from hil.analysis.measure.windows import MINUTE_NS, age_windows, lateness_windows, per_window

MS = 1_000_000
US = 1_000
H = 250 * US  # the plant's step
P = 2 * MS  # the control period


def _regular(first_sample: int, last_sample: int, latency: int = 1 * MS) -> tuple[list, list]:
    """Landings every period, each ``latency`` after its sample: a 1-3 ms saw tooth."""
    samples = list(range(first_sample, last_sample + 1, P))
    return [s + latency for s in samples], samples


def _segments(lands: list[int], samples: list[int], end: int) -> AgeSegments:
    land = np.asarray(lands, dtype=np.int64)
    return AgeSegments(land, np.append(land[1:], np.int64(end)), np.asarray(samples, np.int64))


def _straddling_run() -> AgeSegments:
    """Two minutes of a 1-3 ms saw tooth with one 32 ms excursion across the minute's edge:
    the command computed from the sample at 59.990 s lands at 59.991 s and stays in force until
    the next landing at 60.022 s (peak age 60.022 - 59.990 = 32 ms)."""
    lands, samples = _regular(0, 59_988 * MS)  # the last regular landing: 59.989 s
    lands.append(59_991 * MS)
    samples.append(59_990 * MS)
    more_lands, more_samples = _regular(60_021 * MS, 119_985 * MS)  # next landing 60.022 s
    return _segments(lands + more_lands, samples + more_samples, 119_990 * MS)


def _brute_ages(seg: AgeSegments, grid0: int, h: int) -> np.ndarray:
    """The age at every plant step of every segment, one by one."""
    out = []
    for a, e, s in zip(seg.start.tolist(), seg.end.tolist(), seg.sample.tolist(), strict=True):
        first = grid0 + -(-(a - grid0) // h) * h
        out.append(np.arange(first, e, h, dtype=np.int64) - s)
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def _owned(seg: AgeSegments, lo: int, hi: int) -> AgeSegments:
    mine = (seg.end >= lo) & (seg.end < hi)
    return AgeSegments(seg.start[mine], seg.end[mine], seg.sample[mine])


def _p99_us(values_ns: np.ndarray) -> float:
    return int(np.percentile(values_ns, 99, method="inverted_cdf")) / 1000.0


def test_a_32ms_stall_across_a_minute_edge_counts_whole_in_the_minute_it_ended() -> None:
    seg = _straddling_run()
    w = age_windows(seg, 0, H, 0, MINUTE_NS, 2)
    # The minute of the excursion's end holds it whole, at its end...
    assert w[1]["max_us"] == 32_000.0
    assert w[1]["max_at_ns"] == 60_022 * MS
    # ...and the minute it started in keeps only the saw tooth: nothing clipped into it (a
    # clipped excursion would read 60.000 - 59.990 = 10 ms here).
    assert w[0]["max_us"] == 3_000.0
    assert 0 <= w[0]["max_at_ns"] < MINUTE_NS  # the first of its equal 3 ms peaks
    # Every plant step is counted once: the windows' steps add up to the run's, and the run's
    # largest age (D) is the largest window max.
    whole = age_summary(seg, 0, H)
    assert w[0]["count"] + w[1]["count"] == whole["count"]
    assert max(x["max_us"] for x in w) == whole["max_us"] == 32_000.0
    # Each window's percentiles are those of the ages at its own plant steps (brute force).
    for i, x in enumerate(w):
        ages = _brute_ages(_owned(seg, i * MINUTE_NS, (i + 1) * MINUTE_NS), 0, H)
        assert x["count"] == ages.size
        assert x["p99_us"] == _p99_us(ages)
        assert x["p50_us"] == int(np.percentile(ages, 50, method="inverted_cdf")) / 1000.0


def test_a_windows_p99_sees_an_excursion_that_is_more_than_1pct_of_it() -> None:
    """Windows of 0.1 s around the same excursion: its 124 steps are a third of the window of
    its end, so that window's p99 is near its peak, and the window before (where it started)
    has the saw tooth's p99 only."""
    seg = _straddling_run()
    width = 100 * MS
    origin = 59_900 * MS
    part = _owned(seg, origin, origin + 2 * width)
    w = age_windows(part, 0, H, origin, width, 2)
    for i, x in enumerate(w):
        ages = _brute_ages(_owned(part, origin + i * width, origin + (i + 1) * width), 0, H)
        assert x["p99_us"] == _p99_us(ages)
    assert w[1]["max_us"] == 32_000.0 and w[1]["p99_us"] >= 30_000.0
    assert w[0]["max_us"] == 3_000.0 and w[0]["p99_us"] <= 3_000.0


def test_a_segment_ending_on_an_edge_belongs_to_the_later_window() -> None:
    # [1 ms, 60 s) holding the sample at 0: its peak (60 s) occurs at the landing at 60 s,
    # which is the second window's first instant.
    seg = AgeSegments(
        np.array([1 * MS, MINUTE_NS], np.int64),
        np.array([MINUTE_NS, MINUTE_NS + 5 * MS], np.int64),
        np.array([0, MINUTE_NS - 1 * MS], np.int64),
    )
    w = age_windows(seg, 0, H, 0, MINUTE_NS, 2)
    assert (w[0]["segments"], w[1]["segments"]) == (0, 2)
    assert w[0]["max_us"] is None and w[0]["max_at_ns"] is None
    assert w[1]["max_us"] == 60_000_000.0


def test_lateness_per_window_keeps_each_ticks_whole_lateness_in_the_window_of_its_deadline():
    t_ns = np.arange(0, 120_000 * MS, 1 * MS, dtype=np.int64)
    late = np.full(t_ns.size, 50 * US, dtype=np.int64)
    late[t_ns == 59_999 * MS] = 32 * MS  # the tick due just before the edge woke 32 ms late
    late[t_ns == 90_000 * MS] = 7 * MS
    w = lateness_windows(t_ns / 1e9, late, 0.0, 60.0, 2)
    assert (w[0]["max_us"], w[1]["max_us"]) == (32_000.0, 7_000.0)
    assert w[0]["count"] == w[1]["count"] == 60_000
    for i, x in enumerate(w):
        mine = (t_ns >= i * MINUTE_NS) & (t_ns < (i + 1) * MINUTE_NS)
        assert x["p99_us"] == _p99_us(late[mine])


def test_per_window_leaves_an_unmeasured_figure_none_not_zero() -> None:
    """An on_state run has no wake-up lateness: every window says None (n/a), never 0; the
    command age is still there, and the last (partial) window is counted."""
    seg = _straddling_run()
    series = {"command_age_zenoh": seg, "applied_path": "zenoh"}
    rows = per_window(series, 0, (0, 119_990 * MS), H, MINUTE_NS)
    assert [r["window"] for r in rows] == [0, 1]
    assert all(r["wakeup_lateness_p99_us"] is None for r in rows)
    assert all(r["wakeup_lateness_max_us"] is None for r in rows)
    assert [r["command_age_max_us"] for r in rows] == [3_000.0, 32_000.0]
    assert rows[1]["command_age_max_at_s"] == pytest.approx(60.022)


def test_per_window_over_hil_measure_of_a_run_with_a_stall_across_an_edge(tmp_path) -> None:
    """The same through hil.analysis.measure: a scripted run (tests/synthetic_run.py) whose
    controller stalls 32 ms across the edge of 1 s windows; the window where the stall ended holds
    the run's D, the window before holds only the regular age."""
    from hil.analysis.measure import load_folder_logs, measure
    from tests.synthetic_run import MS as SMS
    from tests.synthetic_run import Loop, write

    loop = Loop(n=1000, controller_stall=(990 * SMS, 32 * SMS))
    write(tmp_path, loop)
    logs = load_folder_logs(tmp_path)
    assert logs is not None
    m = measure(logs)
    rows = per_window(m.series, logs.epoch_ns, m.window_ns, loop.plant_step, 1_000 * SMS)
    assert len(rows) == 2
    d_us = m.timing["command_age_zenoh"]["max_us"]
    assert d_us > 32_000.0  # the stall plus the loop's own age
    assert rows[1]["command_age_max_us"] == d_us
    assert rows[0]["command_age_max_us"] < 5_000.0  # a period and a half at most: no stall
    assert rows[1]["command_age_max_at_s"] > 1.0
    lat = m.series["wakeup_lateness"][1]
    assert max(r["wakeup_lateness_max_us"] for r in rows) == int(lat.max()) / 1000.0
    steps = sum(r["command_age_steps"] for r in rows)
    assert steps == m.timing["command_age_zenoh"]["count"]

"""Sampling-effect metrics (hil/analysis/trace_metrics.py): exact percentiles against numpy, bands,
switching rates, constraint figures, deviation from the ideal trajectory."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.analysis import trace_metrics
from hil.limits import ConstraintFigure

KNOWN = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0, 2.0, 6.0, 5.0, 3.0, 5.0]


@pytest.mark.parametrize("q", [0, 1, 10, 25, 50, 75, 90, 99, 99.9, 100])
def test_percentile_equals_numpy_inverted_cdf_on_known_data(q: float) -> None:
    assert trace_metrics.percentile(KNOWN, q) == np.percentile(KNOWN, q, method="inverted_cdf")
    assert trace_metrics.percentile(KNOWN, q) in KNOWN


def test_percentile_known_values_by_hand() -> None:
    # 1..100: the smallest value with at least q % of the samples at or below it.
    data = np.arange(1, 101, dtype=float)
    assert trace_metrics.percentile(data, 50) == 50.0
    assert trace_metrics.percentile(data, 90) == 90.0
    assert trace_metrics.percentile(data, 99.9) == 100.0
    assert trace_metrics.percentile(data, 100) == 100.0
    assert trace_metrics.percentile(data, 0) == 1.0


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=1, max_size=300),
    st.floats(0, 100),
)
def test_percentile_is_an_exact_sample_on_random_data(values: list[float], q: float) -> None:
    got = trace_metrics.percentile(values, q)
    assert got == np.percentile(values, q, method="inverted_cdf")
    srt = np.sort(values)
    assert got in srt and srt[0] <= got <= srt[-1]
    assert np.count_nonzero(srt <= got) >= q / 100.0 * srt.size


def test_percentile_rejects_empty_and_out_of_range() -> None:
    with pytest.raises(ValueError):
        trace_metrics.percentile([], 50)
    with pytest.raises(ValueError):
        trace_metrics.percentile([1.0], 101)


def test_percentiles_agree_with_the_run_summaries() -> None:
    """The report's percentiles and summary.json's (hil.analysis.measure.stats) are one
    definition."""
    from hil.analysis.measure.stats import summarize_ns

    rng = np.random.default_rng(7)
    ns = np.concatenate([rng.gamma(4.0, 50_000.0, 20_000), rng.uniform(1e6, 5e7, 50)])
    ns = ns.astype(np.int64)
    s = summarize_ns(ns)
    p = trace_metrics.percentiles(ns)
    for q in trace_metrics.PERCENTILES:
        key = trace_metrics._pkey(q)
        assert p[key] / 1000.0 == s[key + "_us"]
    assert p["max"] / 1000.0 == s["max_us"]


def test_percentiles_keys_match_summary_names() -> None:
    p = trace_metrics.percentiles(np.arange(1000.0))
    assert set(p) == {"p50", "p90", "p99", "p999", "max"}
    assert p["p999"] == np.percentile(np.arange(1000.0), 99.9, method="inverted_cdf")


def test_saturation_share_counts_samples_at_the_limit() -> None:
    tau = np.array([3.3, -3.3, 3.297, 1.0, -3.29, np.nan])  # 0.999 * 3.3 = 3.2967
    assert trace_metrics.saturation_share(tau, 3.3) == pytest.approx(3 / 5)
    assert trace_metrics.saturation_share(np.array([np.nan]), 3.3) == 0.0


def test_wrap_angle_half_open_interval() -> None:
    w = trace_metrics.wrap_angle(np.array([math.pi, -math.pi, 3 * math.pi, 0.1, -7.0]))
    assert np.all(w > -math.pi) and np.all(w <= math.pi)
    assert w[0] == pytest.approx(math.pi) and w[1] == pytest.approx(math.pi)
    assert w[4] == pytest.approx(-7.0 + 2 * math.pi)


def test_band_after_reaching_on_a_chattering_signal() -> None:
    t = np.arange(2001) * 1e-3
    # reaching phase: a ramp from 0.5 to 0 over 0.5 s, then +-0.01 chattering
    s = np.where(t < 0.5, 0.5 - t, 0.01 * np.where(np.arange(t.size) % 2 == 0, 1.0, -1.0))
    band = trace_metrics.quasi_sliding_band(t, s)
    assert band.reaching_time == pytest.approx(0.5, abs=2e-3)
    assert band.band_max == pytest.approx(0.01)
    assert band.band_spread == pytest.approx(0.02)
    assert band.band_p99 == pytest.approx(0.01)


def test_band_never_reached_and_boundary_layer_threshold() -> None:
    t = np.linspace(0, 1, 101)
    s = 1.0 + t  # never crosses zero
    assert trace_metrics.quasi_sliding_band(t, s).reaching_time is None
    s2 = np.exp(-5 * t)  # approaches zero without crossing: reached at |s| <= eps
    band = trace_metrics.quasi_sliding_band(t, s2, threshold=0.1)
    assert band.reaching_time == pytest.approx(t[np.argmax(s2 <= 0.1)])


def test_switching_rate_counts_sign_changes_per_second() -> None:
    t = np.arange(1001) * 1e-3  # 1 s
    tau = np.where(np.arange(t.size) % 2 == 0, 3.3, -3.3)
    assert trace_metrics.switching_rate(t, tau) == pytest.approx(1000.0)
    tau0 = np.array([3.3, 0.0, 0.0, 3.3, -3.3, 0.0, -3.3])  # zeros skipped: one change
    assert trace_metrics.switching_rate(np.linspace(0, 1, 7), tau0) == pytest.approx(1.0)


def test_constraint_figure_tolerance_and_bound() -> None:
    ok = ConstraintFigure("v", 1.6 * (1 + 1e-12), 1.6, 1.7)
    assert ok.held and ok.within_bound
    bad = ConstraintFigure("v", 1.65, 1.6, 1.62)
    assert not bad.held and bad.within_bound is False
    assert bad.ratio == pytest.approx(1.65 / 1.6)


def test_deviation_from_ideal_interpolates() -> None:
    ti = np.linspace(0, 1, 1001)
    t = np.linspace(0, 1, 11)
    dev = trace_metrics.deviation_from_ideal(t, t + 0.1, np.zeros(11), ti, ti, np.zeros(1001))
    assert np.allclose(dev, 0.1)


def test_sampling_effects_ignore_gaps_but_not_infinities() -> None:
    t = np.linspace(0.0, 1.0, 5)
    zero = np.zeros(5)
    trace = {
        "t": t,
        "x": zero,
        "y": zero,
        "theta": zero,
        "xd": zero,
        "yd": zero,
        "thetad": zero,
        "v": np.array([0.1, np.nan, 0.5, 0.2, 0.0]),
        "omega": np.array([0, 0, np.inf, 0, 0.0]),
        "tau1": zero,
        "tau2": zero,
    }
    m = trace_metrics.sampling_effects(trace, phi1=1.6, phi2=5.1, varpi1=3.3, varpi2=51.0)
    assert m["constraints"]["v"]["peak"] == 0.5 and m["constraints"]["v"]["held"]
    assert not m["constraints"]["omega"]["held"]
    assert m["bands"] == {"v_tilde": None, "w_tilde": None}

"""Command age (age of information) at every plant step, computed exactly from the landings.

A landing is (a_j, s_j): at a_j the plant started holding a command computed from the sample
taken at s_j. Until the next landing a_(j+1) the age at time t is t - s_j, a saw tooth, and at
every plant step g_i = g0 + i h (h the plant's step) it is g_i - s_j. Its percentiles count,
per landing, the steps whose age is at most v (an arithmetic progression) and bisect on v:
exact (an age some step really had), in memory linear in the number of landings.

D, the quantity of the sampled-data bound (docs/design.md, docs/sampled_data_bound.md), is the
largest age: max over j of a_(j+1) - s_j, the last step before each next landing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hil.analysis.measure.stats import PERCENTILES, empty_summary, summary_from_quantiles
from hil.folder.records import Percentiles


@dataclass(frozen=True)
class AgeSegments:
    """The landings in force over the window: [start, end) holding the sample ``sample``."""

    start: np.ndarray  # ns, a_j
    end: np.ndarray  # ns, a_(j+1) (or the window's end)
    sample: np.ndarray  # ns, s_j

    @property
    def peak(self) -> np.ndarray:
        """The largest age in each segment (at its end)."""
        return self.end - self.sample

    def __len__(self) -> int:
        return int(self.start.size)


def segments(
    land_ns: np.ndarray, sample_ns: np.ndarray, end_ns: int, start_ns: int | None = None
) -> AgeSegments:
    """Segments from landings sorted by time; landings after ``end_ns`` are dropped. With
    ``start_ns`` (t = 0, the plant's first sample) the stretch before the first landing, when the
    plant holds zero torque, is a segment of its own whose age counts from ``start_ns`` (the
    sampled-data bound's assumption A2 counts the age from t = 0)."""
    land = np.asarray(land_ns, dtype=np.int64)
    order = np.argsort(land, kind="stable")
    land, samp = land[order], np.asarray(sample_ns, dtype=np.int64)[order]
    land, samp = land[land <= end_ns], samp[land <= end_ns]
    if start_ns is not None and (land.size == 0 or int(land[0]) > start_ns):
        land = np.concatenate([[np.int64(start_ns)], land])
        samp = np.concatenate([[np.int64(start_ns)], samp])
    end = np.append(land[1:], np.int64(end_ns)) if land.size else land
    return AgeSegments(land, end, samp)


def age_summary(seg: AgeSegments, g0: int, h: int) -> Percentiles:
    """count, p50/p90/p99/p999, max, mean (µs) of the age at every plant step g0 + i h."""
    if len(seg) == 0 or h <= 0:
        return empty_summary()
    # Per segment, the grid indices [lo, hi) of the plant steps inside [start, end).
    lo = np.maximum(-((g0 - seg.start) // h), 0)  # ceil((start - g0) / h)
    hi = np.maximum(-((g0 - seg.end) // h), lo)
    n = hi - lo
    total = int(n.sum())
    if total == 0:
        return empty_summary()
    # Ages at the first and last step of each segment bound the search.
    nonempty = n > 0
    first_age = (g0 + lo * h - seg.sample)[nonempty]
    last_age = (g0 + (hi - 1) * h - seg.sample)[nonempty]
    # The plant also steps to each landing's instant (it integrates lazily to every event),
    # so the largest age of all is the segment peak a_(j+1) - s_j: D itself.
    amin, amax = int(first_age.min()), int(seg.peak.max())
    # Mean: each segment's ages form an arithmetic progression.
    mean = float(((first_age + last_age) / 2.0 * n[nonempty]).sum() / total)
    quantiles: dict[str, int] = {}
    for name, q in PERCENTILES:
        need = max(1, int(np.ceil(q / 100.0 * total)))
        a, b = amin, amax  # the answer lies in [a, b]: at least need steps <= b
        while a < b:
            mid = (a + b) // 2
            top = (seg.sample + mid - g0) // h  # per segment, the last step with age <= mid
            if int(np.clip(top - lo + 1, 0, n).sum()) >= need:  # steps with age <= mid
                b = mid
            else:
                a = mid + 1
        quantiles[name] = a
    return summary_from_quantiles(total, quantiles, amax, mean)


def max_age(seg: AgeSegments) -> int | None:
    """D: the largest age over the window (ns), None without landings."""
    return int(seg.peak.max()) if len(seg) else None


def envelope(
    seg: AgeSegments, t0: int, bins: int = 2000
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t in s from ``t0``, min age, max age) per time bin, in seconds: a plot of millions of
    steps drawn from a few thousand points. The max of a bin is the largest segment peak (or
    partial peak) inside it."""
    if len(seg) == 0:
        z = np.zeros(0)
        return z, z, z
    edges = np.linspace(int(seg.start[0]), int(seg.end[-1]), bins + 1)
    t = (edges[:-1] + edges[1:]) / 2.0
    # Age at the bin edges (piecewise linear between landings) and the peaks inside each bin.
    idx = np.clip(np.searchsorted(seg.start, edges, side="right") - 1, 0, len(seg) - 1)
    at_edges = edges - seg.sample[idx]
    bmin = np.minimum(at_edges[:-1], at_edges[1:])
    bmax = np.maximum(at_edges[:-1], at_edges[1:])
    # One segment-long index array at a time, clipped in place, and the ages cast by the
    # ufunc: an hour at 1 kHz has 3.6 M segments, 29 MB per array.
    b = np.searchsorted(edges, seg.end, side="right")
    np.clip(b - 1, 0, bins - 1, out=b)
    np.maximum.at(bmax, b, seg.peak)
    b = np.searchsorted(edges, seg.start, side="right")
    np.clip(b - 1, 0, bins - 1, out=b)
    np.minimum.at(bmin, b, seg.start - seg.sample)
    return (t - t0) / 1e9, bmin / 1e9, bmax / 1e9

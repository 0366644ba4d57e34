"""Figures per time window (a soak's minutes) from one measurement of the whole run.

Windows are [origin + k w, origin + (k + 1) w). Nothing is clipped at their edges:

- wake-up lateness: each tick belongs to the window of its deadline, with its whole lateness;
- command age: each age segment (one landing in force,
:class:`hil.analysis.measure.age.AgeSegments`)
  belongs, whole, to the window in which its peak falls, i.e. its end (the next landing). A
  stall across an edge is then one excursion of its full size in the window where it ended,
  never two small ones. A window's age percentiles are those of the plant steps of its
  segments (:func:`hil.analysis.measure.age.age_summary` on the same grid as the whole run), so the
  windows' step counts add up to the run's, and its max is the largest peak among them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypedDict

import numpy as np

from hil.analysis.measure.age import AgeSegments, age_summary
from hil.analysis.measure.stats import summarize_ns
from hil.folder.records import Percentiles

MINUTE_NS = 60_000_000_000


class WindowFigures(TypedDict):
    """One window of :func:`per_window` (s from the run's epoch, µs; None: not measured)."""

    window: int
    start_s: float
    end_s: float
    wakeup_lateness_p99_us: float | None
    wakeup_lateness_max_us: float | None
    wakeup_lateness_count: int | None
    command_age_p99_us: float | None
    command_age_max_us: float | None
    command_age_max_at_s: float | None  # when the window's largest age ended
    command_age_steps: int | None  # plant steps of the window's age segments


def lateness_windows(
    t_s: np.ndarray, late_ns: np.ndarray, origin_s: float, width_s: float, n: int
) -> list[Percentiles]:
    """Wake-up lateness summary (µs, :func:`hil.analysis.measure.stats.summarize_ns`) per window,
    each tick in the window of its deadline ``t_s`` (seconds on the same clock as ``origin_s``)."""
    t = np.asarray(t_s, dtype=float)
    late = np.asarray(late_ns, dtype=np.int64)
    k = np.clip(np.floor((t - origin_s) / width_s).astype(np.int64), 0, n - 1)
    return [summarize_ns(late[k == i]) for i in range(n)]


def age_windows(
    seg: AgeSegments, grid0_ns: int, step_ns: int, origin_ns: int, width_ns: int, n: int
) -> list[Percentiles]:
    """Command-age summary (µs) per window on the plant's step grid ``grid0_ns``/``step_ns``
    (module docstring), with ``max_at_ns``: the end of the largest peak's segment (None in a
    window without a segment). Segments ending outside the windows go to the first or last."""
    k = np.clip((np.asarray(seg.end, np.int64) - origin_ns) // np.int64(width_ns), 0, n - 1)
    out = []
    for i in range(n):
        part = AgeSegments(*(a[k == i] for a in (seg.start, seg.end, seg.sample)))
        summary = age_summary(part, grid0_ns, step_ns)
        summary["max_at_ns"] = None
        if len(part):
            j = int(np.argmax(part.peak))
            summary["max_us"] = int(part.peak[j]) / 1000.0
            summary["max_at_ns"] = int(part.end[j])
        summary["segments"] = len(part)
        out.append(summary)
    return out


def per_window(
    series: Mapping[str, Any],
    epoch_ns: int,
    window_ns: tuple[int, int],
    step_ns: int,
    width_ns: int = MINUTE_NS,
) -> list[WindowFigures]:
    """Wake-up lateness and applied-path command age (p99 and max, µs) per window of
    ``width_ns`` from the run's epoch, from :func:`hil.analysis.measure.measure`'s ``series`` and
    ``window_ns`` (first, last plant sample). A figure the run did not measure (no wake-up
    lateness in ``on_state`` or lockstep runs) is None in every window, not 0."""
    w0, w1 = int(window_ns[0]), int(window_ns[1])
    n = max(1, -(-(w1 - int(epoch_ns)) // int(width_ns)))  # windows up to w1, at least 1
    late = series.get("wakeup_lateness")
    lat = [{}] * n if late is None else lateness_windows(*late, 0.0, width_ns / 1e9, n)
    seg = series.get(f"command_age_{series.get('applied_path', 'zenoh')}")
    age = [{}] * n if seg is None else age_windows(seg, w0, step_ns, epoch_ns, width_ns, n)
    out: list[WindowFigures] = []
    for i, (w, a) in enumerate(zip(lat, age, strict=True)):
        at = a.get("max_at_ns")
        out.append(
            {
                "window": i,
                "start_s": i * width_ns / 1e9,
                "end_s": (i + 1) * width_ns / 1e9,
                "wakeup_lateness_p99_us": w.get("p99_us"),
                "wakeup_lateness_max_us": w.get("max_us"),
                "wakeup_lateness_count": w.get("count"),
                "command_age_p99_us": a.get("p99_us"),
                "command_age_max_us": a.get("max_us"),
                "command_age_max_at_s": None if at is None else (at - epoch_ns) / 1e9,
                "command_age_steps": a.get("count"),
            }
        )
    return out

"""Figures of a report: each one a PNG (matplotlib, Agg backend, no display) and its data.

Every figure is also written as data beside its picture (issue 5, part 5): a :class:`Figure`
carries the plotted columns so the writer can save them as CSV.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

# Plots beyond this many points are decimated for drawing only; the data files stay complete.
MAX_DRAWN_POINTS = 20_000
LIMIT_STYLE = {"color": "red", "linestyle": "--", "linewidth": 1.2}
BOUND_STYLE = {"color": "darkorange", "linestyle": ":", "linewidth": 1.2}


@dataclass
class Figure:
    """One picture and the columns it was drawn from (written as ``<name>.csv``)."""

    name: str
    title: str
    png: bytes
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    caption: str = ""

    def write(self, folder: Path, prefix: str) -> tuple[Path, Path]:
        png_path = folder / f"{prefix}{self.name}.png"
        csv_path = folder / f"{prefix}{self.name}.csv"
        png_path.write_bytes(self.png)
        write_columns(csv_path, self.columns)
        return png_path, csv_path


def write_columns(path: Path, columns: Mapping[str, np.ndarray]) -> None:
    """Columns of unequal length are padded with empty cells (histograms beside CDFs)."""
    names = list(columns)
    arrays = [np.asarray(columns[n]).ravel() for n in names]
    rows = max((a.size for a in arrays), default=0)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(names)
        for i in range(rows):
            w.writerow([repr(float(a[i])) if i < a.size else "" for a in arrays])


def _png(fig: plt.Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def _decimate(*arrays: np.ndarray) -> list[np.ndarray]:
    n = arrays[0].size
    if n <= MAX_DRAWN_POINTS:
        return list(arrays)
    # Keep each stride's min and max so chattering envelopes and peaks survive decimation.
    step = int(np.ceil(n / (MAX_DRAWN_POINTS / 2)))
    idx = np.arange(0, n, step)
    out = [arrays[0][idx]]
    for a in arrays[1:]:
        pad = (-n) % step
        padded = np.concatenate([a, np.full(pad, a[-1])]).reshape(-1, step)
        lo, hi = padded.min(axis=1), padded.max(axis=1)
        both = np.where(np.arange(idx.size) % 2 == 0, hi, lo)
        out.append(both)
    return out


#: Robot, reference and ideal trajectory: each its own colour AND line style (told apart in
#: grey print too).
TRAJECTORY_STYLES = (
    ("reference", {"color": "black", "linestyle": "--", "linewidth": 1.0}),
    # the ideal trajectory is drawn over the robot's: thin dark dots on a wide light line, so
    # that both stay visible where they coincide
    ("ideal", {"color": "darkgreen", "linestyle": (0, (1.5, 1.5)), "linewidth": 1.4}),
    ("robot", {"color": "tab:blue", "linestyle": "-", "linewidth": 2.6, "alpha": 0.6}),
)
OTHER_STYLES = (
    {"color": "tab:orange", "linestyle": "-.", "linewidth": 1.2},
    {"color": "tab:purple", "linestyle": (0, (5, 1)), "linewidth": 1.2},
    {"color": "tab:brown", "linestyle": "-", "linewidth": 0.9},
)


def _trajectory_style(label: str, i: int) -> dict:
    for key, style in TRAJECTORY_STYLES:
        if label.startswith(key):
            return style
    return OTHER_STYLES[i % len(OTHER_STYLES)]


def trajectory(
    series: Sequence[tuple[str, np.ndarray, np.ndarray]], title: str = "Trajectory in the plane"
) -> Figure:
    """Robot and reference in the (X, Y) plane (the paper's Figures 2 and 7); labels starting
    "robot", "reference", "ideal" get fixed, distinct colours and line styles."""
    fig, ax = plt.subplots(figsize=(6, 5))
    cols: dict[str, np.ndarray] = {}
    for i, (label, x, y) in enumerate(series):
        xs, ys = (
            (x, y)
            if x.size <= MAX_DRAWN_POINTS
            else (x[:: x.size // MAX_DRAWN_POINTS + 1], y[:: x.size // MAX_DRAWN_POINTS + 1])
        )
        ax.plot(xs, ys, label=label, **_trajectory_style(label, i))
        cols[f"{label}_x"] = x
        cols[f"{label}_y"] = y
    if series:
        first = next((s for s in series if s[0].startswith("robot")), series[0])
        ax.plot(first[1][0], first[2][0], "ko", markersize=4, label=f"{first[0]} start")
    ax.set_xlabel("X [m]")
    ax.set_ylabel("Y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    return Figure("trajectory", title, _png(fig), {k: np.asarray(v) for k, v in cols.items()})


def signal_with_limits(
    name: str,
    title: str,
    unit: str,
    t: np.ndarray,
    series: Sequence[tuple[str, np.ndarray]],
    limit: float | None = None,
    bound: float | None = None,
) -> Figure:
    """A signal against time with its limit of (2) as red dashed lines (as in the paper's
    Figures 3-6) and, where known, the sampled-data bound as dotted lines."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    cols: dict[str, np.ndarray] = {"t": t}
    for label, y in series:
        td, yd = _decimate(t, y)
        ax.plot(td, yd, linewidth=0.9, label=label)
        cols[label] = y
    if limit is not None:
        ax.axhline(limit, label=f"limit ±{limit:g}", **LIMIT_STYLE)
        ax.axhline(-limit, **LIMIT_STYLE)
        cols["limit"] = np.array([limit])
    if bound is not None and np.isfinite(bound):
        ax.axhline(bound, label=f"sampled-data bound ±{bound:.3g}", **BOUND_STYLE)
        ax.axhline(-bound, **BOUND_STYLE)
        cols["bound"] = np.array([bound])
    ax.set_xlabel("t [s]")
    ax.set_ylabel(unit)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols)


def histogram_and_cdf(name: str, title: str, samples: Mapping[str, np.ndarray]) -> Figure:
    """Histogram and empirical CDF of latency samples (microseconds), one curve per path."""
    fig, (ax_h, ax_c) = plt.subplots(1, 2, figsize=(9, 3.4))
    cols: dict[str, np.ndarray] = {}
    for label, values in samples.items():
        v = np.sort(np.asarray(values, dtype=float))
        if v.size == 0:
            continue
        counts, edges = np.histogram(v, bins=min(80, max(10, v.size // 20)))
        ax_h.stairs(counts, edges, label=label)
        cdf = np.arange(1, v.size + 1) / v.size
        ax_c.plot(v, cdf, label=label, linewidth=1.0)
        cols[f"{label}_bin_left_us"] = edges[:-1]
        cols[f"{label}_bin_right_us"] = edges[1:]
        cols[f"{label}_count"] = counts
        cols[f"{label}_sorted_us"] = v
        cols[f"{label}_cdf"] = cdf
    for ax in (ax_h, ax_c):
        ax.set_xlabel("µs")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    ax_h.set_ylabel("count")
    ax_h.set_yscale("log")
    ax_c.set_ylabel("fraction ≤ x")
    ax_h.set_title("histogram")
    ax_c.set_title("CDF")
    fig.suptitle(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols)


def over_time(
    name: str, title: str, unit: str, series: Mapping[str, tuple[np.ndarray, np.ndarray]]
) -> Figure:
    """Series each with its own time axis (wake-up lateness, jitter)."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    cols: dict[str, np.ndarray] = {}
    for label, (t, y) in series.items():
        td, yd = _decimate(np.asarray(t, float), np.asarray(y, float))
        ax.plot(td, yd, linewidth=0.8, label=label)
        cols[f"{label}_t"] = t
        cols[label] = y
    ax.set_xlabel("t [s]")
    ax.set_ylabel(unit)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols)


def stacked(
    name: str,
    title: str,
    panels: Sequence[tuple[str, str, np.ndarray, np.ndarray, float | None]],
) -> Figure:
    """One signal per axis, stacked (v~ above w~: their scales differ by an order of
    magnitude): (label, unit, t, y, threshold) per panel; a threshold (the boundary layer's
    eps) is drawn as grey dotted lines at +-threshold."""
    fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.4 * len(panels)), sharex=True)
    axes = np.atleast_1d(axes)
    cols: dict[str, np.ndarray] = {}
    for ax, (label, unit, t, y, thr) in zip(axes, panels, strict=True):
        td, yd = _decimate(np.asarray(t, float), np.asarray(y, float))
        ax.plot(td, yd, linewidth=0.8, label=label)
        if thr:
            ax.axhline(thr, color="grey", linestyle=":", linewidth=1.0, label=f"±{thr:g}")
            ax.axhline(-thr, color="grey", linestyle=":", linewidth=1.0)
        ax.set_ylabel(unit)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
        cols[f"{label}_t"] = np.asarray(t)
        cols[label] = np.asarray(y)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols)


def age_envelope(
    name: str,
    title: str,
    envelopes: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
    d_star: float | None,
    threshold: float | None,
    stalls: Sequence[tuple[float, float]] = (),
) -> Figure:
    """Command age over time per path, from :func:`hil.measure.age.envelope` (t s, min s,
    max s per bin), in ms; D* as a red dashed line, the stall threshold dotted, stalls marked.
    The first path is drawn as a filled band, the others (shadow paths) as thin lines."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    cols: dict[str, np.ndarray] = {}
    for i, (label, (t, lo, hi)) in enumerate(envelopes.items()):
        if i == 0:
            ax.fill_between(t, lo * 1e3, hi * 1e3, step="mid", alpha=0.6, label=label)
        else:
            ax.plot(t, hi * 1e3, linewidth=0.7, color="grey", linestyle="--", label=f"{label} max")
        cols[f"{label}_t_s"] = t
        cols[f"{label}_min_ms"] = lo * 1e3
        cols[f"{label}_max_ms"] = hi * 1e3
    if d_star is not None and np.isfinite(d_star):
        ax.axhline(d_star * 1e3, label=f"D* {d_star * 1e3:.3g} ms", **LIMIT_STYLE)
        cols["d_star_ms"] = np.array([d_star * 1e3])
    if threshold is not None:
        ax.axhline(
            threshold * 1e3, label=f"stall threshold {threshold * 1e3:.3g} ms", **BOUND_STYLE
        )
        cols["stall_threshold_ms"] = np.array([threshold * 1e3])
    if stalls:
        st = np.array(stalls, dtype=float)
        ax.plot(st[:, 0], st[:, 1] * 1e3, "kx", markersize=6, label="stalls")
        cols["stall_t_s"] = st[:, 0]
        cols["stall_age_ms"] = st[:, 1] * 1e3
    ax.set_xlabel("t [s]")
    ax.set_ylabel("command age [ms]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols)


def against_parameter(
    name: str,
    title: str,
    xlabel: str,
    ylabel: str,
    x: np.ndarray,
    series: Mapping[str, np.ndarray],
    hline: float | None = None,
    mark_x: float | None = None,
) -> Figure:
    """Sweep figures: a metric against Ts or delay, one curve per value of the other axis."""
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    cols: dict[str, np.ndarray] = {"x": np.asarray(x, float)}
    for label, y in series.items():
        ax.plot(x, y, "o-", markersize=3, linewidth=1.0, label=label)
        cols[label] = np.asarray(y, float)
    if hline is not None:
        ax.axhline(hline, label=f"limit {hline:g}", **LIMIT_STYLE)
    if mark_x is not None:
        ax.axvline(mark_x, color="black", linestyle="-.", linewidth=1.0, label="break point")
    xs = np.asarray(x, float)
    positive = xs[np.isfinite(xs) & (xs > 0)]
    if positive.size == xs.size and xs.size:
        ax.set_xscale("log")
    elif positive.size:
        # delay 0 belongs on the axis: log spacing above the smallest positive value
        ax.set_xscale("symlog", linthresh=float(positive.min()))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize=7)
    ax.set_title(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols)

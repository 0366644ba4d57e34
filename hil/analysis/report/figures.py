"""Figures of a report: each one a PNG (matplotlib, Agg backend, no display) and the columns
it was drawn from, which the writer saves as CSV beside it."""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

# Series beyond this many points are drawn from min/max envelopes (envelope_indices) in at
# most ENVELOPE_BINS time bins; data files stay complete up to MAX_DATA_ROWS samples and hold
# the drawn samples beyond (an hour at 1 kHz would write GBs of CSV per figure otherwise).
MAX_DRAWN_POINTS = 20_000
ENVELOPE_BINS = 2_000
MAX_DATA_ROWS = 200_000
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
        png_path, csv_path = (folder / f"{prefix}{self.name}.{ext}" for ext in ("png", "csv"))
        png_path.write_bytes(self.png)
        write_columns(csv_path, self.columns)
        return png_path, csv_path


WRITE_CHUNK_ROWS = 16_384


def write_columns(path: Path, columns: Mapping[str, np.ndarray]) -> None:
    """Columns as CSV, unequal ones padded with empty cells; each cell ``repr(float(value))``,
    the shortest text that reads back the same. A chunk at a time by ``map`` and ``str.join``,
    not a ``csv`` call per row: millions of rows in seconds."""
    names = list(columns)
    arrays = [np.asarray(columns[n]).ravel() for n in names]
    rows = max((a.size for a in arrays), default=0)
    with open(path, "w", newline="") as f:
        csv.writer(f).writerow(names)  # the header may need quoting; numbers never do
        for r0 in range(0, rows, WRITE_CHUNK_ROWS):
            r1 = min(rows, r0 + WRITE_CHUNK_ROWS)
            cells = []
            for a in arrays:
                part = a[r0:r1].astype(float, copy=False).tolist() if r0 < a.size else []
                text = list(map(repr, part))
                cells.append(text + [""] * (r1 - r0 - len(text)))
            f.write("\r\n".join(map(",".join, zip(*cells, strict=True))))
            f.write("\r\n")


def _png(fig: plt.Figure) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def envelope_indices(
    t: np.ndarray, ys: Sequence[np.ndarray], bins: int | None = None
) -> np.ndarray:
    """The samples to draw of series ``ys`` over a non-decreasing axis ``t`` (time, or sample
    index): the first and last, and in each of ``bins`` equal bins of ``t`` the first sample at
    each series' minimum, at its maximum and the first NaN, so that every bin's extremes (a limit
    crossing, a one-sample spike) and every gap are drawn. Sorted, unique; all samples up to
    :data:`MAX_DRAWN_POINTS`, ``bins`` by default as many as keep within it (at most
    :data:`ENVELOPE_BINS`). Linear in the number of samples."""
    t = np.asarray(t, dtype=float)
    n = t.size
    if n <= MAX_DRAWN_POINTS:
        return np.arange(n)
    if bins is None:
        bins = min(ENVELOPE_BINS, MAX_DRAWN_POINTS // (3 * max(1, len(ys))))
    lo_t, hi_t = float(t[0]), float(t[-1])
    inner = np.linspace(lo_t, hi_t, bins + 1)[1:-1] if hi_t > lo_t else np.zeros(0)
    starts = np.unique(np.concatenate([[0], np.searchsorted(t, inner, side="left")]))
    starts = starts[starts < n]
    bin_of = np.repeat(np.arange(starts.size, dtype=np.int32), np.diff(np.append(starts, n)))
    picks = [np.array([0, n - 1])]
    for y in ys:
        y = np.asarray(y, dtype=float)
        for reduce in (np.fmin, np.fmax):  # NaN-ignoring: a bin's extremes of its known values
            ext = reduce.reduceat(y, starts)
            picks.append(_first_per_bin(np.flatnonzero(y == ext[bin_of]), bin_of))
        missing = np.flatnonzero(np.isnan(y))
        if missing.size:
            picks.append(_first_per_bin(missing, bin_of))
    return np.unique(np.concatenate(picks))


def _first_per_bin(hits: np.ndarray, bin_of: np.ndarray) -> np.ndarray:
    """Of sorted sample indices ``hits``, the first in each bin."""
    return hits[np.diff(bin_of[hits], prepend=-1) != 0]


def _labels(ax: plt.Axes, xlabel: str, ylabel: str, title: str, **legend: Any) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3, which=legend.pop("which", "major"))
    ax.legend(**legend)
    ax.set_title(title)


def _drawn(t: np.ndarray, ys: Sequence[np.ndarray]) -> np.ndarray | None:
    """:func:`envelope_indices`, or None when every sample is drawn."""
    t = np.asarray(t)
    return envelope_indices(t, ys) if t.size > MAX_DRAWN_POINTS else None


def _plot_drawn(
    ax: plt.Axes,
    label: str,
    xy: tuple[np.ndarray, np.ndarray],
    idx: np.ndarray | None,
    keys: tuple[str, str],
    cols: dict[str, np.ndarray],
    captions: list[str],
    **style: Any,
) -> None:
    """Plot the samples ``idx`` (None: all) of ``xy``, keep their data under ``keys`` and, for
    a series drawn from its envelope, say so in ``captions``."""
    x, y = xy
    ax.plot(x if idx is None else x[idx], y if idx is None else y[idx], label=label, **style)
    cols.update(zip(keys, (_data(x, idx), _data(y, idx)), strict=True))
    if idx is not None:
        captions.append(f"{label}: {_envelope_caption(np.size(x), idx)}")


def _time_series(
    ax: plt.Axes, label: str, t: np.ndarray, y: np.ndarray, cols: dict, captions: list[str]
) -> None:
    """One series with its own time axis (sorted by time first), as a thin line."""
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    if t.size > 1 and np.any(t[1:] < t[:-1]):
        order = np.argsort(t, kind="stable")
        t, y = t[order], y[order]
    keys = (f"{label}_t", label)
    _plot_drawn(ax, label, (t, y), _drawn(t, [y]), keys, cols, captions, linewidth=0.8)


def _data(full: np.ndarray, idx: np.ndarray | None) -> np.ndarray:
    """A column of a figure's data file: complete up to :data:`MAX_DATA_ROWS` samples, else the
    drawn samples (every bin's extremes; the whole series is in trace.csv or the hop logs)."""
    full = np.asarray(full)
    return full if idx is None or full.size <= MAX_DATA_ROWS else full[idx]


def _envelope_caption(n: int, idx: np.ndarray | None) -> str:
    if idx is None:
        return ""
    where = "every sample"
    if n > MAX_DATA_ROWS:
        where = f"the {idx.size} drawn samples (the complete series is in the folder's trace.csv "
        where += "or hop logs)"
    return (
        f"{n} samples drawn as {idx.size}: the minimum and maximum of each time bin, so every "
        f"peak and limit crossing shows; the data file holds {where}."
    )


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


def trajectory(
    series: Sequence[tuple[str, np.ndarray, np.ndarray]], title: str = "Trajectory in the plane"
) -> Figure:
    """Robot and reference in the (X, Y) plane (the paper's Figures 2 and 7); labels starting
    "robot", "reference", "ideal" get fixed, distinct colours and line styles."""
    fig, ax = plt.subplots(figsize=(6, 5))
    cols: dict[str, np.ndarray] = {}
    captions = []
    for i, (label, x, y) in enumerate(series):
        # long paths: in each bin of samples, those at the smallest and largest X and Y
        idx = _drawn(np.arange(np.size(x)), [x, y])
        style = next((st for key, st in TRAJECTORY_STYLES if label.startswith(key)), None)
        style = style or OTHER_STYLES[i % len(OTHER_STYLES)]
        keys = (f"{label}_x", f"{label}_y")
        _plot_drawn(ax, label, (x, y), idx, keys, cols, captions, **style)
    if series:
        first = next((s for s in series if s[0].startswith("robot")), series[0])
        ax.plot(first[1][0], first[2][0], "ko", markersize=4, label=f"{first[0]} start")
    ax.set_aspect("equal", adjustable="datalim")
    _labels(ax, "X [m]", "Y [m]", title, fontsize=8)
    return Figure("trajectory", title, _png(fig), cols, " ".join(captions))


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
    idx = _drawn(t, [y for _, y in series])
    td = t if idx is None else t[idx]
    cols: dict[str, np.ndarray] = {"t": _data(t, idx)}
    for label, y in series:
        ax.plot(td, y if idx is None else y[idx], linewidth=0.9, label=label)
        cols[label] = _data(y, idx)
    _limit_lines(ax, cols, limit, bound)
    _labels(ax, "t [s]", unit, title, fontsize=8, loc="upper right")
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols, _envelope_caption(np.size(t), idx))


def _limit_lines(ax: plt.Axes, cols: dict, limit: float | None, bound: float | None) -> None:
    """The limit of (2) (red dashed) and the sampled-data bound (dotted) as ± lines."""
    if limit is not None:
        ax.axhline(limit, label=f"limit ±{limit:g}", **LIMIT_STYLE)
        ax.axhline(-limit, **LIMIT_STYLE)
        cols["limit"] = np.array([limit])
    if bound is not None and np.isfinite(bound):
        ax.axhline(bound, label=f"sampled-data bound ±{bound:.3g}", **BOUND_STYLE)
        ax.axhline(-bound, **BOUND_STYLE)
        cols["bound"] = np.array([bound])


#: Time bins of a switching signal's band: each drawn as its min-max range and its mean.
BAND_BINS = 400


def switching_band(
    name: str,
    title: str,
    unit: str,
    t: np.ndarray,
    series: Sequence[tuple[str, np.ndarray]],
    limit: float | None = None,
    note: str = "",
) -> Figure:
    """A signal switching faster than a plot shows (a sliding-mode torque: a solid block of lines
    otherwise): per time bin its min-max range (envelope) and mean (duty); the limit of (2)."""
    t = np.asarray(t, dtype=float)
    bins = max(1, min(BAND_BINS, t.size // 4))
    starts = np.unique(np.searchsorted(t, np.linspace(t[0], t[-1], bins + 1)[:-1]))
    mid = t[starts] if starts.size < 2 else np.append((t[starts[:-1]] + t[starts[1:]]) / 2, t[-1])
    fig, ax = plt.subplots(figsize=(7, 3.2))
    # The samples themselves (as signal_with_limits writes them), then the drawn bins.
    idx = _drawn(t, [y for _, y in series])
    cols: dict[str, np.ndarray] = {"t": _data(t, idx)}
    cols.update({label: _data(np.asarray(y), idx) for label, y in series})
    cols["t_bin_s"] = mid
    for i, (label, y) in enumerate(series):
        y = np.asarray(y, dtype=float)
        lo, hi = np.fmin.reduceat(y, starts), np.fmax.reduceat(y, starts)
        sums = np.add.reduceat(np.nan_to_num(y), starts)
        mean = sums / np.maximum(np.add.reduceat(np.isfinite(y).astype(float), starts), 1)
        color = f"C{i}"
        ax.fill_between(mid, lo, hi, color=color, alpha=0.25, linewidth=0, step="mid",
                        label=f"{label}: min-max per bin")  # fmt: skip
        ax.plot(mid, mean, color=color, linewidth=1.2, label=f"{label}: mean per bin")
        cols.update({f"{label}_min": lo, f"{label}_max": hi, f"{label}_mean": mean})
    _limit_lines(ax, cols, limit, None)
    _labels(ax, "t [s]", unit, title, fontsize=7, loc="upper right")
    fig.tight_layout()
    width = (t[-1] - t[0]) / bins if t.size > 1 else 0.0
    caption = (
        f"Drawn per {width * 1e3:.3g} ms bin: the shaded band is the signal's min-max range "
        "(its envelope), the line its mean (its duty)."
    )
    return Figure(name, title, _png(fig), cols, (caption + " " + note).strip())


#: A latency histogram's axis ends here (a quantile of the pooled samples) when the largest
#: sample is far beyond it: one outlier would squeeze every other sample into one bar.
CLIP_QUANTILE = 0.999
CLIP_FACTOR = 3.0


def _clip(samples: Mapping[str, np.ndarray]) -> tuple[float | None, float]:
    """Where the axis ends (None: nothing clipped), and the smallest sample."""
    pooled = np.concatenate([np.asarray(v, dtype=float).ravel() for v in samples.values()])
    pooled = pooled[np.isfinite(pooled)]
    if pooled.size < 10:
        return None, 0.0
    q = float(np.quantile(pooled, CLIP_QUANTILE))
    return q * 1.05 if q > 0 and pooled.max() > CLIP_FACTOR * q else None, float(pooled.min())


def histogram_and_cdf(name: str, title: str, samples: Mapping[str, np.ndarray]) -> Figure:
    """Histogram and empirical CDF of latency samples (microseconds), one curve per path."""
    fig, (ax_h, ax_c) = plt.subplots(1, 2, figsize=(9, 3.4))
    cols: dict[str, np.ndarray] = {}
    captions: list[str] = []
    clip, low = _clip(samples) if samples else (None, 0.0)
    for label, values in samples.items():
        v = np.sort(np.asarray(values, dtype=float))
        if v.size == 0:
            continue
        shown = v if clip is None else v[v <= clip]
        counts, edges = np.histogram(shown, bins=min(80, max(10, shown.size // 20)))
        if clip is not None and shown.size < v.size:
            out = v[v > clip]
            largest = ", ".join(f"{x:.0f}" for x in out[::-1][:5])
            captions.append(
                f"{label}: {out.size} samples beyond the axis ({clip:.0f} µs, 1.05 x the "
                f"pooled p99.9) are left out of the drawing, not of the data: largest {largest} µs."
            )
        ax_h.stairs(counts, edges, label=label)
        cdf = np.arange(1, v.size + 1) / v.size
        idx = cdf_indices(v.size)
        ax_c.plot(v[idx], cdf[idx], label=label, linewidth=1.0)
        kept = slice(None) if v.size <= MAX_DATA_ROWS else idx
        cols |= {f"{label}_bin_left_us": edges[:-1], f"{label}_bin_right_us": edges[1:]}
        cols |= {f"{label}_count": counts, f"{label}_sorted_us": v[kept], f"{label}_cdf": cdf[kept]}
        if idx.size < v.size:
            data = "every sample" if v.size <= MAX_DATA_ROWS else "the drawn points"
            captions.append(
                f"{label}: CDF of {v.size} samples drawn at {idx.size} points, denser towards "
                f"the tail (the largest 1000 all drawn); its data holds {data}."
            )
    _labels(ax_h, "µs", "count", "histogram", fontsize=8)
    _labels(ax_c, "µs", "fraction ≤ x", "CDF", fontsize=8)
    ax_h.set_yscale("log")
    if clip is not None:
        # both ends: left to itself the axis keeps the clipped outliers' margin on the left
        ax_c.set_xlim(low - 0.05 * (clip - low), clip)
    fig.suptitle(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols, " ".join(captions))


def cdf_indices(n: int, points: int = 2_000, tail: int = 1_000) -> np.ndarray:
    """Which of ``n`` sorted samples an empirical CDF draws: all up to :data:`MAX_DRAWN_POINTS`,
    else ``points`` evenly spaced, ``points`` evenly on a log scale of the distance from the top
    (the tail, p99.9 and beyond, where stalls show), the largest ``tail``, the first and last."""
    if n <= MAX_DRAWN_POINTS:
        return np.arange(n)
    even = np.linspace(0, n - 1, points).round().astype(np.int64)
    top = (n - 1) - (np.geomspace(1, n, points).round().astype(np.int64) - 1)
    last = np.arange(max(0, n - tail), n)
    return np.unique(np.concatenate([[0, n - 1], even, top, last]))


def over_time(
    name: str, title: str, unit: str, series: Mapping[str, tuple[np.ndarray, np.ndarray]]
) -> Figure:
    """Series each with its own time axis (wake-up lateness, jitter)."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    cols: dict[str, np.ndarray] = {}
    captions = []
    for label, (t, y) in series.items():
        _time_series(ax, label, t, y, cols, captions)
    _labels(ax, "t [s]", unit, title, fontsize=8)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols, " ".join(captions))


def stacked(
    name: str, title: str, panels: Sequence[tuple[str, str, np.ndarray, np.ndarray, float | None]]
) -> Figure:
    """One signal per axis, stacked (v~ above w~: their scales differ tenfold): (label, unit, t,
    y, threshold) per panel; a threshold (the boundary layer's eps) as grey dotted ± lines."""
    fig, axes = plt.subplots(len(panels), 1, figsize=(7, 2.4 * len(panels)), sharex=True)
    axes = np.atleast_1d(axes)
    cols: dict[str, np.ndarray] = {}
    captions = []
    for ax, (label, unit, t, y, thr) in zip(axes, panels, strict=True):
        _time_series(ax, label, t, y, cols, captions)
        if thr:
            ax.axhline(thr, color="grey", linestyle=":", linewidth=1.0, label=f"±{thr:g}")
            ax.axhline(-thr, color="grey", linestyle=":", linewidth=1.0)
        _labels(ax, "", unit, "", fontsize=8, loc="upper right")  # the figure has the title
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols, " ".join(captions))


def age_envelope(
    name: str,
    title: str,
    envelopes: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]],
    d_star: float | None,
    threshold: float | None,
    stalls: Sequence[tuple[float, float]] = (),
) -> Figure:
    """Command age (ms) per path from :func:`hil.analysis.measure.age.envelope`: the first path a
    filled band, the others (shadow paths) thin lines; D* red dashed, the stall threshold dotted."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    cols: dict[str, np.ndarray] = {}
    for i, (label, (t, lo, hi)) in enumerate(envelopes.items()):
        if i == 0:
            ax.fill_between(t, lo * 1e3, hi * 1e3, step="mid", alpha=0.6, label=label)
        else:
            ax.plot(t, hi * 1e3, linewidth=0.7, color="grey", linestyle="--", label=f"{label} max")
        cols |= {f"{label}_t_s": t, f"{label}_min_ms": lo * 1e3, f"{label}_max_ms": hi * 1e3}
    if d_star is not None and np.isfinite(d_star):
        ax.axhline(d_star * 1e3, label=f"D* {d_star * 1e3:.3g} ms", **LIMIT_STYLE)
        cols["d_star_ms"] = np.array([d_star * 1e3])
    if threshold is not None:
        label = f"stall threshold {threshold * 1e3:.3g} ms"
        ax.axhline(threshold * 1e3, label=label, **BOUND_STYLE)
        cols["stall_threshold_ms"] = np.array([threshold * 1e3])
    if stalls:
        st = np.array(stalls, dtype=float)
        ax.plot(st[:, 0], st[:, 1] * 1e3, "kx", markersize=6, label="stalls")
        cols |= {"stall_t_s": st[:, 0], "stall_age_ms": st[:, 1] * 1e3}
    _labels(ax, "t [s]", "command age [ms]", title, fontsize=8, loc="upper right")
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
    xs = np.asarray(x, float)
    cols: dict[str, np.ndarray] = {"x": xs}
    for label, y in series.items():
        ax.plot(x, y, "o-", markersize=3, linewidth=1.0, label=label)
        cols[label] = np.asarray(y, float)
    if hline is not None:
        ax.axhline(hline, label=f"limit {hline:g}", **LIMIT_STYLE)
    if mark_x is not None:
        ax.axvline(mark_x, color="black", linestyle="-.", linewidth=1.0, label="break point")
    positive = xs[np.isfinite(xs) & (xs > 0)]
    if positive.size == xs.size and xs.size:
        ax.set_xscale("log")
    elif positive.size:
        # delay 0 belongs on the axis: log spacing above the smallest positive value
        ax.set_xscale("symlog", linthresh=float(positive.min()))
    _labels(ax, xlabel, ylabel, title, fontsize=7, which="both")
    fig.tight_layout()
    return Figure(name, title, _png(fig), cols)

"""Figures in the style of the paper's Figures 2-20, each with its data as CSV beside the PNG.

Limits of (2) are drawn as red dashed lines, as in the paper.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from hil.folder.trace_csv import write_trace_csv
from hil.sim.core import SimResult

MAX_POINTS = 30000  # drawn per run at most: every step-th sample of a longer trace
Runs = Sequence[tuple[str, SimResult]]  # (legend label, run) of the runs drawn together


def _save(fig: plt.Figure, path: Path, cols: list[str], data: list[np.ndarray]) -> Path:
    """Write the figure to ``path`` (PNG) and its data, cut to the shortest column, beside it."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    n = min(len(d) for d in data)
    write_trace_csv(path.with_suffix(".csv"), cols, np.column_stack([d[:n] for d in data]))
    return path


def trajectory(path: Path, title: str, runs: Runs, reference: SimResult) -> Path:
    """Robot position in the (X, Y) plane against the virtual robot (Figures 2, 7, 15, 18)."""
    fig, ax = plt.subplots(figsize=(6, 5))
    step = max(1, len(reference.trace) // MAX_POINTS)
    cols: list[str] = ["xd", "yd"]
    data = [reference.column("xd")[::step], reference.column("yd")[::step]]
    ax.plot(data[0], data[1], "k--", lw=1.2, label="reference")
    for label, run in runs:
        x, y = run.column("x")[::step], run.column("y")[::step]
        ax.plot(x, y, lw=1.2, label=label)
        ax.plot(x[:1], y[:1], "o", ms=4)
        cols += [f"x_{label}", f"y_{label}"]
        data += [x, y]
    ax.set(xlabel="X (m)", ylabel="Y (m)", title=title)
    ax.axis("equal")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path, cols, data)


def over_time(
    path: Path, title: str, ylabel: str, columns: list[str], runs: Runs, limit: float | None = None
) -> Path:
    """Signals over time with the constraint of (2) as red dashed lines (Figures 3-6, 8-14,
    16, 17, 19, 20)."""
    fig, ax = plt.subplots(figsize=(7, 3.6))
    first = runs[0][1]
    step = max(1, len(first.trace) // MAX_POINTS)
    t = first.column("t")[::step]
    cols, data = ["t"], [t]
    for label, run in runs:
        for c in columns:
            y = run.column(c)[::step][: len(t)]
            name = c if len(runs) == 1 else f"{c}_{label}"
            ax.plot(
                t[: len(y)], y, lw=0.8, label=name if (len(runs) > 1 or len(columns) > 1) else None
            )
            cols.append(name)
            data.append(y)
    if limit is not None:
        ax.axhline(limit, color="red", ls="--", lw=1.2, label="limit")
        ax.axhline(-limit, color="red", ls="--", lw=1.2)
    ax.set(xlabel="t (s)", ylabel=ylabel, title=title)
    ax.grid(True, alpha=0.3)
    if len(cols) > 2 or limit is not None:
        ax.legend(loc="best", fontsize=8)
    return _save(fig, path, cols, data)

"""``clock.png`` of a run across hosts: the controller's offset estimates to the plant's clock
over the run, each with its uncertainty (half the round trip of the exchange used), around
their median, so that a drift, a step or a widening bound shows."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from hil.folder import layout
from hil.folder.clocks import ClockTrack, read_track


def clock_png(track: ClockTrack) -> bytes | None:
    """The plot as PNG bytes (clock.png and the report's figure), None without estimates."""
    matplotlib.use("Agg")
    if track.at_ns.size == 0:
        return None
    t = (track.at_ns - track.at_ns[0]) / 1e9
    mid = float(np.median(track.offset_ns))
    dev = (track.offset_ns - mid) / 1e3
    unc = track.uncertainty_ns / 1e3
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.fill_between(t, dev - unc, dev + unc, alpha=0.3, step="post", label="+- uncertainty")
    ax.step(t, dev, where="post", label="estimate")
    ax.set_xlabel("controller time since its first estimate (s)")
    ax.set_ylabel(f"offset - {mid / 1e9:.6f} s (us)")
    ax.set_title("plant clock minus controller clock (RFC 5905 minimum-delay filter)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def write_clock_plot(run_dir: Path) -> None:
    """clock.png of a run across lab hosts (the bench wrote its topology.json, which names the
    plot when there are estimates), from the folder's estimates; a plot never costs the run its
    folder."""
    if not (run_dir / layout.TOPOLOGY).is_file():
        return
    try:
        png = clock_png(read_track(run_dir))
        if png is not None:
            (run_dir / layout.CLOCK_PLOT).write_bytes(png)
    except Exception as exc:
        print(f"warning: clock plot not written: {exc}", file=sys.stderr)

"""The controller's stamps on the plant's clock, when the two clocks provably differ.

Every stamp is its own host's ``CLOCK_MONOTONIC`` (docs/clocks.md). When the controller ran on
another host, its stamps are converted to the plant's clock as the hop logs are read, each with
the controller's estimate of the offset in force when it was taken (``clock-controller.csv``,
runtime.clocksync: the newest at or before it; the first before that). Figures of one host (the
controller's compute, the command age D) do not change; figures that cross hosts (a state's
flight to the controller, a command's to the plant) are corrected, each within the estimate's
uncertainty (half the round trip of the exchange used). Nothing is converted when the
estimates hold 0 (one host: the bound is exact, so it always does) or when there are none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.folder.clocks import read_track

# The columns stamped on the controller's clock (a stamp of 0 means none and stays 0); the
# other columns of these tables are the plant's stamps, carried back in the State.
CONTROLLER_CLOCK: dict[str, tuple[str, ...]] = {
    "ticks": ("deadline_ns", "wake_ns", "state_recv_ns", "compute_start_ns", "compute_end_ns",
              "zenoh_send_ns", "can_send_ns"),
    "state_rx": ("recv_ns",),
    "can_tx": ("send_ns", "bus_end_ns"),
    "cmd_rx": ("compute_start_ns", "send_ns"),
}  # fmt: skip


def to_plant_clock(tables: dict[str, dict[str, np.ndarray]], folder: Path | None) -> None:
    """Convert the controller-clock columns of ``tables`` in place (see the module docstring)."""
    track = read_track(folder) if folder is not None else None
    if track is None or not track.differ:
        return
    for table, columns in CONTROLLER_CLOCK.items():
        for c in columns:
            col = tables.get(table, {}).get(c)
            if col is not None and col.size:
                stamped = col != 0
                col[stamped] = col[stamped] + track.offset_at(col[stamped])

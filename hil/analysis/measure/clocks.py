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

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from runtime.clocksync import CLOCK_FILE

# The columns stamped on the controller's clock (a stamp of 0 means none and stays 0); the
# other columns of these tables are the plant's stamps, carried back in the State.
CONTROLLER_CLOCK: dict[str, tuple[str, ...]] = {
    "ticks": ("deadline_ns", "wake_ns", "state_recv_ns", "compute_start_ns", "compute_end_ns",
              "zenoh_send_ns", "can_send_ns"),
    "state_rx": ("recv_ns",),
    "can_tx": ("send_ns", "bus_end_ns"),
    "cmd_rx": ("compute_start_ns", "send_ns"),
}  # fmt: skip


@dataclass(frozen=True)
class ClockTrack:
    """The controller's estimates: at (its clock), offset (plant - controller), uncertainty."""

    at_ns: np.ndarray
    offset_ns: np.ndarray
    uncertainty_ns: np.ndarray

    @property
    def differ(self) -> bool:
        """The clocks provably differ: most estimates exclude 0."""
        if self.at_ns.size == 0:
            return False
        return bool(np.median(np.abs(self.offset_ns) > self.uncertainty_ns) > 0.5)

    def offset_at(self, t_ns: np.ndarray) -> np.ndarray:
        i = np.clip(np.searchsorted(self.at_ns, t_ns, side="right") - 1, 0, self.at_ns.size - 1)
        return self.offset_ns[i]

    def facts(self) -> dict[str, Any]:
        """For the run folder: how many estimates, the offset and the uncertainty."""
        if self.at_ns.size == 0:
            return {"estimates": 0, "related": False}
        return {
            "estimates": int(self.at_ns.size),
            "related": True,
            "converted": self.differ,
            "offset_ns_median": float(np.median(self.offset_ns)),
            "offset_ns_range": [float(self.offset_ns.min()), float(self.offset_ns.max())],
            "uncertainty_ns_median": float(np.median(self.uncertainty_ns)),
            "uncertainty_ns_max": float(self.uncertainty_ns.max()),
        }


def read_track(folder: Path) -> ClockTrack:
    """The estimates in ``folder/clock-controller.csv`` (none when it is absent)."""
    try:
        lines = (folder / CLOCK_FILE).read_text().splitlines()[1:]
    except OSError:
        lines = []
    fields = [line.split(",") for line in lines]
    ok = [f for f in fields if len(f) == 8 and all(x.lstrip("-").isdigit() for x in f)]
    rows = [(int(f[3]), int(f[6]), int(f[7])) for f in ok]
    return ClockTrack(*np.asarray(rows, dtype=np.int64).reshape(-1, 3).T)


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

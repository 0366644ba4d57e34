"""The controller's clock probe as the run folder holds it (``clock-controller.csv``,
:data:`hil.folder.layout.CLOCK`, written by runtime.clocksync): its offset estimates to the
plant's clock, read by the bench (topology.json's clock facts) and by the analysis
(:mod:`hil.analysis.measure.clocks` converts the controller's stamps with them)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hil.folder import layout


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
        lines = (folder / layout.CLOCK).read_text().splitlines()[1:]
    except OSError:
        lines = []
    fields = [line.split(",") for line in lines]
    ok = [f for f in fields if len(f) == 8 and all(x.lstrip("-").isdigit() for x in f)]
    rows = [(int(f[3]), int(f[6]), int(f[7])) for f in ok]
    return ClockTrack(*np.asarray(rows, dtype=np.int64).reshape(-1, 3).T)

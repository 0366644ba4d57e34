"""A run's one result, as the report and ``hil compare`` read it: the folder's measurement.

Every timing figure, message count and the certificate of a run come from :mod:`hil.measure`,
made once when the run ended (summary.json's ``timing``, ``messages`` and ``certificate``, and
series.npz's per-sample series; :func:`hil.measure.folder.measured`). Nothing here computes a
figure of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hil.folder import RunFolder
from hil.folder.records import Certificate
from hil.measure.figures import Measurement
from hil.measure.folder import measured

SOURCE = "summary.json and series.npz (hil.measure, measured once when the run ended)"


@dataclass
class RunResult:
    """summary.json's ``timing``, ``messages``, ``certificate`` and the series behind them."""

    timing: dict[str, Any]
    messages: dict[str, Any]
    certificate: Certificate | None
    measurement: Measurement  # the series for plots
    epoch_ns: int | None  # the run's time origin (trace.csv's t = 0)
    source: str = SOURCE

    @property
    def applied_path(self) -> str | None:
        if self.certificate and self.certificate.get("path"):
            return str(self.certificate["path"])
        path = self.measurement.series.get("applied_path")
        return str(path) if path else None


def run_result(folder: RunFolder) -> RunResult | None:
    """The run's result, or None for a simulation folder (no timing and no hop logs)."""
    m = measured(folder)
    if m is None:
        return None
    return RunResult(m.timing, m.messages or {}, m.certificate, m, m.epoch_ns)

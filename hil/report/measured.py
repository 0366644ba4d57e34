"""A run's one result, as the report and ``hil compare`` read it.

Every timing figure, message count and the certificate of a run come from :mod:`hil.measure`
(docs/realtime.md, "Timing figures"): ``hil run`` writes them into summary.json's
``timing``, ``messages`` and ``certificate``, and this module hands exactly those on. The
per-sample series that plots need (latency per command, wake-up lateness, command age) come
from the same pipeline run on the folder's hop logs (:func:`hil.measure.folder.measure_logs`).
Nothing here computes a figure of its own.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from hil.measure.figures import Measurement
from hil.report.folder import Folder

SUMMARY_SOURCE = "summary.json (hil.measure)"
HOP_LOG_SOURCE = "hop logs (hil.measure.measure_folder)"


@dataclass
class RunResult:
    """summary.json's ``timing``, ``messages``, ``certificate`` and the series behind them."""

    timing: dict[str, Any]
    messages: dict[str, Any]
    certificate: dict[str, Any] | None
    measurement: Measurement | None  # the hop logs' measurement (series for plots), if any
    epoch_ns: int | None  # the run's time origin (trace.csv's t = 0)
    source: str
    #: summary.json's figures equal the hop logs' measurement (None: one of them is missing).
    agree: bool | None = None

    @property
    def applied_path(self) -> str | None:
        if self.certificate and self.certificate.get("path"):
            return str(self.certificate["path"])
        if self.measurement is not None:
            path = self.measurement.series.get("applied_path")
            return str(path) if path else None
        return None


def _plain(obj: Any) -> Any:
    """numpy scalars to Python, through JSON as summary.json stores them."""
    import numpy as np

    def conv(o: Any) -> Any:
        if isinstance(o, np.integer):
            return int(o)
        if isinstance(o, np.floating):
            return float(o)
        if isinstance(o, np.bool_):
            return bool(o)
        raise TypeError(type(o))

    return json.loads(json.dumps(obj, default=conv))


def measure_run_folder(folder: Folder) -> tuple[Measurement | None, int | None]:
    """The hop logs' measurement of a run folder and its epoch (None, None: no hop logs)."""
    from hil.measure.folder import measure_logs
    from hil.measure.logs import load_folder_logs

    logs = load_folder_logs(folder.path)
    if logs is None or logs.plant is None:
        return None, None
    return measure_logs(logs, folder.scenario), logs.epoch_ns


def run_result(folder: Folder) -> RunResult | None:
    """The run's result, or None for a simulation folder (no timing and no hop logs).

    summary.json's objects come first (they are what the run reported); a summary without them
    (written before they existed) falls back to the hop logs' measurement.
    """
    summary = folder.summary
    m, epoch = measure_run_folder(folder)
    has_summary = isinstance(summary.get("timing"), dict) and "certificate" in summary
    if not has_summary and m is None:
        return None
    if has_summary:
        timing = summary["timing"]
        messages = summary.get("messages") if isinstance(summary.get("messages"), dict) else {}
        cert = summary.get("certificate") if isinstance(summary.get("certificate"), dict) else None
        source = SUMMARY_SOURCE
    else:
        assert m is not None
        timing, messages, cert = _plain(m.timing), _plain(m.messages), _plain(m.certificate)
        source = HOP_LOG_SOURCE
    agree = None
    if has_summary and m is not None:
        agree = (
            _plain(m.timing) == timing
            and _plain(m.messages) == messages
            and _plain(m.certificate) == cert
        )
    return RunResult(timing, messages or {}, cert, m, epoch, source, agree)

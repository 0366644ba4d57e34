"""The run's measurements: one pipeline from the services' hop logs to every figure.

:func:`measure` (in :mod:`hil.measure.figures`) turns a run's two hop logs
(:mod:`protocol.hoplog`) into the contract's ``timing``, ``messages`` and ``certificate``
objects; everything that shows a timing figure reads that one result. Definitions of every
figure: docs/realtime.md, "Timing figures".
"""

from hil.measure.figures import BoundInputs, Measurement, measure
from hil.measure.logs import RunLogs, load_folder_logs, load_recording_logs

__all__ = [
    "BoundInputs",
    "Measurement",
    "RunLogs",
    "load_folder_logs",
    "load_recording_logs",
    "measure",
]

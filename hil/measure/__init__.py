"""The run's measurements: one pipeline from the services' hop logs (:mod:`protocol.hoplog`)
to every figure, :func:`measure` (:mod:`hil.measure.figures`)."""

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

"""The run's measurements: one pipeline from the services' hop logs (:mod:`protocol.hoplog`)
to every figure, :func:`measure` (:mod:`hil.analysis.measure.figures`)."""

from hil.analysis.measure.figures import measure
from hil.analysis.measure.logs import load_folder_logs

__all__ = ["load_folder_logs", "measure"]

"""The offline simulator's Python API (used by ``hil sim``, ``hil paper``, sweeps, reports):
:func:`simulate` (one loop on floats), :func:`simulate_batch` (N loops on numpy arrays),
:func:`write_run_folder` and :func:`jitter_samples_from` (``jitter_kind = "replay"``)."""

from hil.folder.replay import jitter_samples_from
from hil.sim.core import BatchResult, RobotVariation, SimResult, simulate, simulate_batch
from hil.sim.folder import write_run_folder

__all__ = [
    "BatchResult", "RobotVariation", "SimResult", "jitter_samples_from", "simulate",
    "simulate_batch", "write_run_folder",
]  # fmt: skip

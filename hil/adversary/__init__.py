"""The worst disturbance within |d1| <= s1, |d2| <= s2, searched on the batch path (the loops:
:mod:`hil.adversary.loop`, the search: :mod:`hil.adversary.search`) by ``hil sweep`` and
``hil margin`` with ``--worst-disturbance``."""

from hil.adversary.loop import MODES, Schedule, run_loops, scenario_schedule
from hil.adversary.search import worst_disturbance

__all__ = ["MODES", "Schedule", "run_loops", "scenario_schedule", "worst_disturbance"]

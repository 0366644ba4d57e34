"""The worst disturbance within |d1| <= s1, |d2| <= s2, searched on the batch path (the loops:
:mod:`hil.sim.adversary.loop`, the search: :mod:`hil.sim.adversary.search`) by ``hil sweep`` and
``hil margin`` with ``--worst-disturbance``."""

from hil.sim.adversary.loop import MODES, Schedule, run_loops, scenario_schedule
from hil.sim.adversary.search import worst_disturbance

__all__ = ["MODES", "Schedule", "run_loops", "scenario_schedule", "worst_disturbance"]

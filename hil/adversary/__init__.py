"""The worst disturbance within |d1| <= s1, |d2| <= s2, searched on the batch path.

:mod:`hil.adversary.loop` runs N closed loops whose disturbance is chosen by the loop itself
(bang-bang, switching when a command lands) over a replayed landing schedule;
:mod:`hil.adversary.search` searches the switching patterns (the fixed bang-bang patterns, then
cross-entropy over per-block choices) for the one that drives |v|/phi1 or |omega|/phi2 highest.
``hil sweep --worst-disturbance`` runs it at every grid point (:mod:`hil.sweep.worst`),
``hil margin --worst-disturbance`` at every scale (:mod:`hil.margin`).
"""

from hil.adversary.loop import MODES, LoopPeaks, Schedule, run_loops, scenario_schedule
from hil.adversary.search import WorstDisturbance, worst_disturbance

__all__ = [
    "MODES",
    "LoopPeaks",
    "Schedule",
    "WorstDisturbance",
    "run_loops",
    "scenario_schedule",
    "worst_disturbance",
]

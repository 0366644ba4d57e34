"""How conservative the certificate is for one scenario: D* against the age at which the worst
disturbance found really breaks (2) (docs/sampled_data_bound.md, section 10).

The scenario runs at period ``ts`` with every command landing ``delay`` after its sample (no
jitter), so every command age is at most ts + delay; :func:`hil.analysis.margin.search.find_margin`
scales that timing by k under the worst disturbance searched, and the age of the replay at k*
is the empirical break.
"""

from __future__ import annotations

import dataclasses

from hil.analysis.margin.record import MarginRecord
from hil.analysis.margin.search import MarginOptions, find_margin
from hil.analysis.margin.timing import from_scenario
from hil.scenario import Scenario


def empirical_break(
    scenario: Scenario, ts: float, delay: float, *, seeds: int = 16, duration: float = 5.0
) -> MarginRecord:
    """The margin record of ``scenario`` at (ts, delay) under the worst disturbance found; its
    ``age_at_break_s`` is the empirical break, ``conservatism`` that over D*."""
    timing = dataclasses.replace(scenario.timing, ts=ts, delay=delay, jitter=0.0)
    run = dataclasses.replace(scenario.run, duration=duration)
    sc = dataclasses.replace(scenario, timing=timing, run=run)
    # From a short age (the paper's Ts = 1 ms) the break may lie a hundred times further.
    opts = MarginOptions(seeds=seeds, duration=duration, worst=True, k_max=1024.0)
    return find_margin(sc, from_scenario(sc, 1), opts)

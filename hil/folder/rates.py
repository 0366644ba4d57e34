"""The rates of a run's ``timing`` (summary.json): each one count over what it counts against.

One definition for a robot's run (:mod:`hil.analysis.measure.figures` writes each rate with
:func:`ratio`) and for a fleet (:mod:`hil.analysis.fleet_report` pools the robots' counts with
:func:`pooled`): a fleet's rate is the same count over the same denominator, summed over its
robots, so one robot's fleet has its robot's rate exactly (docs/fleet.md).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

#: rate -> (the count, what it is counted over), keys of summary.json's ``timing``.
RATES: dict[str, tuple[str, str]] = {
    "deadline_miss_rate": ("deadline_misses", "slots"),
    "plant_deadline_miss_rate": ("plant_deadline_misses", "plant_slots"),
    "samples_without_command_rate": ("samples_without_command", "samples_judged"),
    "late_commands_rate": ("late_commands", "samples_judged"),
}


def ratio(count: int, over: int) -> float | None:
    """``count / over``; None (not measured) when there is nothing to count over."""
    return count / over if over else None


def _measured(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def pooled(timings: Iterable[Mapping[str, Any]], rate: str) -> float | None:
    """``rate`` over several runs: their counts summed over their denominators summed. A run
    that did not measure it (absent, e.g. deadline misses in on_state) adds to neither."""
    count, over = RATES[rate]
    pairs = [(t.get(count), t.get(over)) for t in timings]
    pairs = [(n, d) for n, d in pairs if _measured(n) and _measured(d)]
    return ratio(sum(n for n, _ in pairs), sum(d for _, d in pairs)) if pairs else None

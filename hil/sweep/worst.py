"""``hil sweep --worst-disturbance``: each grid point under the worst disturbance found.

Instead of one loop per point under the scenario's own disturbance, each point (Ts, delay,
jitter, seed) gets a search (:func:`hil.sim.adversary.search.worst_disturbance`) over ``POPULATION``
loops x ``ROUNDS`` rounds from around the scenario's initial state, within the scenario's s1, s2;
its row reports the worst loop found (same columns as :func:`hil.sweep.runner.point_row`, plus
``disturbance``, the pattern in words). Ctrl-C keeps the groups already done.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from controller_service.laws.guard import LawFault, LawFaultError
from hil.folder.records import Summary
from hil.folder.scenario_view import view
from hil.limits import PEAK_KEYS
from hil.provenance import Toml
from hil.scenario import Scenario, build_loop, resolved_dict
from hil.sim.adversary.loop import initial_states, scenario_schedule
from hil.sim.adversary.search import worst_disturbance
from hil.sim.certificate import CertificateFigures, certificate
from hil.sweep.grid import SweepGrid, SweepRow, points_label
from hil.sweep.runner import LAW_FAULT_RECORD, SweepOutcome, point_row, scenario_at, worst_age

POPULATION = 64
ROUNDS = 3
SPREAD = 0.05  # m, rad, m/s, rad/s around the scenario's initial state


def _summary(best: Any) -> Summary:
    return {
        **{k: best.peaks[k] for k in PEAK_KEYS.values()},
        "final_position_error": best.peaks["max_late_error"],
        "rms_position_error": float("nan"),
        "violations": {"worst": int(best.broke)},
        "commands_dropped": 0,
    }


def _faulted_row(p: Any, fault: LawFault, cert: CertificateFigures, limits: Any) -> SweepRow:
    """The row of a point whose search stopped at a law fault: no peaks, the fault."""
    nan = float("nan")
    summary = {**dict.fromkeys(PEAK_KEYS.values(), nan), "final_position_error": nan}
    summary |= {"rms_position_error": nan, "violations": {}, "commands_dropped": 0}
    summary["law_fault"] = fault.to_dict()
    row = point_row(p, summary, cert, limits, None, None, True)
    row[LAW_FAULT_RECORD] = fault.to_dict()
    row["disturbance"] = None
    return row


def run_worst_sweep(
    scenario: Scenario,
    grid: SweepGrid,
    duration: float,
    progress: Callable[[float, int, int], None] | None = None,
    on_group: Callable[[list[SweepRow]], None] | None = None,
) -> tuple[SweepOutcome, Toml]:
    """:func:`hil.sweep.runner.run_sweep` with the worst disturbance searched at every point."""
    outcome = SweepOutcome()
    loop = build_loop(scenario)
    resolved = resolved_dict(scenario, loop[0], loop[2])
    sv = view(resolved)
    try:
        at = 0
        for ts, points in grid.by_ts(scenario.timing.seed):
            for i, p in enumerate(points):
                at += 1
                sc = scenario_at(scenario, ts, duration)
                timing = dataclasses.replace(sc.timing, delay=p.delay, jitter=p.jitter, seed=p.seed)
                sc = dataclasses.replace(sc, timing=timing)
                schedule = scenario_schedule(sc, POPULATION)
                init = initial_states(sc, POPULATION, SPREAD, p.seed)
                cert = certificate(sv, ts, worst_age(p, sv.jitter_kind))
                try:
                    best = worst_disturbance(
                        sc, schedule, init, rounds=ROUNDS, seed=p.seed, loop=loop
                    )
                except LawFaultError as exc:  # the law failed in a loop: the point is a FAIL
                    outcome.rows.append(_faulted_row(p, exc.fault, cert, sv.limits))
                    continue
                row = point_row(p, _summary(best), cert, sv.limits, None, None, True)
                row["violation"] = best.broke
                row["disturbance"] = f"{best.describe()} (worst of {best.loops} loops)"
                outcome.rows.append(row)
                outcome.robot_steps += best.loops * schedule.samples
                if progress is not None:
                    done = (i + 1) * schedule.samples // len(points)
                    label = points_label([p], at, len(grid), "point")
                    progress(ts, done, schedule.samples, label=label)
            if on_group is not None:
                on_group(outcome.rows)
            outcome.groups_done += 1
    except KeyboardInterrupt:
        outcome.interrupted = True
    return outcome, resolved


def worst_at_break(rows: list[SweepRow], first: Mapping[str, Any] | None) -> str | None:
    """The disturbance that broke the limit at the sweep's break point, in words."""
    if first is None:
        return None
    for r in rows:
        if all(np.isclose(r[k], first[k]) for k in ("ts", "delay", "jitter")) and r["violation"]:
            return str(r.get("disturbance"))
    return None

"""Running a sweep on the simulator's batch path, one batch per Ts.

Each grid point becomes one robot of its Ts group's batch (``hil.sim.RobotVariation`` with the
point's delay, jitter and seed). Every robot's summary gives the constraint peaks and the
tracking error; the traces of groups up to ``RECORD_LIMIT`` robots are kept for the quasi-sliding
band (v~, w~ telemetry of the unified laws). Ctrl-C keeps the groups already done.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from controller_service.laws.guard import LawFault
from hil.analysis import trace_metrics
from hil.folder.records import Summary
from hil.folder.scenario_view import view
from hil.limits import LIMIT_REL_TOL
from hil.provenance import Toml
from hil.scenario import Scenario, build_loop, resolved_dict, scenario_dict
from hil.sim import BatchResult, RobotVariation, simulate_batch
from hil.sim.certificate import CertificateFigures, certificate
from hil.sim.core import Progress
from hil.sweep.grid import CertifiedBreak, SweepGrid, SweepPoint, SweepRow, points_label

RECORD_LIMIT = 64
SWEEP_JSON = "sweep.json"  # holds the first law fault's whole record (hil.sweep.outputs)
LAW_FAULT_RECORD = "law_fault_record"  # a row's key for it, taken out when the rows are written
#: (ts, samples done, samples in this group; keyword ``label``: the grid points running now,
#: hil.sweep.grid.points_label)
ProgressFn = Callable[..., None]


@dataclass
class SweepOutcome:
    rows: list[SweepRow] = field(default_factory=list)
    interrupted: bool = False
    groups_done: int = 0
    robot_steps: int = 0


def scenario_at(scenario: Scenario, ts: float, duration: float) -> Scenario:
    timing = dataclasses.replace(scenario.timing, ts=ts)
    run = dataclasses.replace(scenario.run, duration=duration)
    return dataclasses.replace(scenario, timing=timing, run=run)


def _band(trace: np.ndarray, columns: list[str], name: str, eps: float) -> float | None:
    if name not in columns:
        return None
    t, x = trace[:, columns.index("t")], trace[:, columns.index(name)]
    return trace_metrics.quasi_sliding_band(t, x, eps).band_p99


def point_row(
    point: SweepPoint,
    summary: Summary,
    cert: CertificateFigures,
    limits: Any,
    band_v: float | None,
    band_w: float | None,
    complete: bool,
) -> SweepRow:
    max_v = float(summary["max_abs_v"])
    max_w = float(summary["max_abs_omega"])
    n_viol = sum(int(v) for v in summary.get("violations", {}).values())
    nonfinite = int(summary.get("nonfinite_steps") or 0)
    fault = summary.get("law_fault")
    tol = 1 + LIMIT_REL_TOL
    v_bound, w_bound = cert.v_bound, cert.w_bound
    within = None if v_bound is None else bool(max_v <= v_bound * tol and max_w <= w_bound * tol)
    return {
        "ts": point.ts,
        "delay": point.delay,
        "jitter": point.jitter,
        "seed": point.seed,
        "age": point.ts + point.delay + point.jitter,
        "final_position_error": float(summary["final_position_error"]),
        "rms_position_error": float(summary["rms_position_error"]),
        "max_abs_v": max_v,
        "max_abs_omega": max_w,
        "max_abs_tau1": float(summary["max_abs_tau1"]),
        "max_abs_tau2": float(summary["max_abs_tau2"]),
        "overshoot_v": max_v / limits.phi1,
        "overshoot_omega": max_w / limits.phi2,
        "band_v": band_v,
        "band_w": band_w,
        "violations": n_viol,
        # a state that became non-finite breaks (2) as surely as a limit (hil.verdict)
        "violation": n_viol > 0 or nonfinite > 0,
        "nonfinite_steps": nonfinite,
        # the law failed at this point: never "held" (hil.sweep.grid.break_points)
        "law_fault": None if fault is None else LawFault.from_dict(fault).sentence(SWEEP_JSON),
        "v_bound": v_bound,
        "w_bound": w_bound,
        "certified": cert.held,
        "within_bound": within,
        "commands_dropped": int(summary.get("commands_dropped", 0)),
        "complete": complete,
    }


def worst_age(point: SweepPoint, jitter_kind: str) -> float:
    """The point's worst command age beyond Ts: its delay plus the jitter's bound (uniform; four
    standard deviations of a normal jitter)."""
    return point.delay + (4.0 * point.jitter if jitter_kind == "normal" else point.jitter)


def simulate_points(
    sc: Scenario, points: Sequence[SweepPoint], record: bool, progress: Progress | None = None
) -> tuple[list[SweepRow], BatchResult]:
    """One batch of ``points`` (one Ts, the scenario ``sc`` at it) and their rows, each with the
    certificate of the design at the point's worst age (the resolved controller table has auto
    lam/rho filled in) and, where ``record`` kept the traces, the quasi-sliding band."""
    robots = [RobotVariation(delay=p.delay, jitter=p.jitter, jitter_seed=p.seed) for p in points]
    record_at = range(len(points)) if record else ()
    result = simulate_batch(sc, robots, record=record_at, progress=progress)
    sv = view(result.resolved)
    # Points of a group share few (delay, jitter) pairs: certify each pair once.
    certs: dict[float, CertificateFigures] = {}
    rows = []
    complete = not result.interrupted
    for i, p in enumerate(points):
        worst = worst_age(p, sv.jitter_kind)
        fault = result.summaries[i].get("law_fault")
        if worst not in certs:
            certs[worst] = certificate(sv, sc.timing.ts, worst)
        trace = result.traces.get(i)
        bv = bw = None
        if trace is not None and len(trace) > 1:
            bv = _band(trace, result.columns, "v_tilde", sv.eps1)
            bw = _band(trace, result.columns, "w_tilde", sv.eps2)
        row = point_row(p, result.summaries[i], certs[worst], sv.limits, bv, bw, complete)
        if fault is not None:  # the whole record (its traceback) goes to sweep.json, not the CSV
            row[LAW_FAULT_RECORD] = fault
        rows.append(row)
    return rows, result


def run_sweep(
    scenario: Scenario,
    grid: SweepGrid,
    duration: float,
    progress: ProgressFn | None = None,
    on_group: Callable[[list[SweepRow]], None] | None = None,
) -> tuple[SweepOutcome, Toml]:
    """All groups of the grid; returns the outcome and the resolved scenario (provenance)."""
    outcome = SweepOutcome()
    resolved: Toml = {}
    try:
        groups = grid.by_ts(scenario.timing.seed)
        for k, (ts, points) in enumerate(groups, 1):
            label = points_label(points, k, len(groups))
            report = None if progress is None else functools.partial(progress, ts, label=label)
            sc = scenario_at(scenario, ts, duration)
            rows, result = simulate_points(sc, points, len(points) <= RECORD_LIMIT, report)
            resolved = resolved or result.resolved
            outcome.rows += rows
            outcome.robot_steps += len(points) * int(result.summaries[0]["samples"])
            if on_group is not None:
                on_group(outcome.rows)
            if result.interrupted:
                outcome.interrupted = True
                break
            outcome.groups_done += 1
    except KeyboardInterrupt:
        outcome.interrupted = True
    return outcome, resolved


def certified_break(scenario: Scenario, grid: SweepGrid) -> CertifiedBreak:
    """The certificate's own prediction over the whole grid (run or not): the point of the
    smallest age Ts + worst delay at which (2) is not guaranteed (None when every point is
    certified). Not a frontier: points of a larger age may be certified; the pages list the
    points run that are not (hil.sweep.outputs.certificate_sentence)."""
    try:
        controller, _ref, context = build_loop(scenario)
        resolved = resolved_dict(scenario, controller, context)
    except Exception:
        resolved = scenario_dict(scenario)
    sv = view(resolved)
    first = None
    for ts, d, j in itertools.product(grid.ts, grid.delay, grid.jitter):
        # The worst delay as each row's ``certified`` has it (the jitter's bound, not j).
        worst = worst_age(SweepPoint(ts, d, j, 0), sv.jitter_kind)
        c = certificate(sv, ts, worst)
        if c.held is False and (first is None or ts + worst < first["age"]):
            first = {"ts": ts, "delay": d, "jitter": j, "age": ts + worst}
    return CertifiedBreak(first_uncertified=first)

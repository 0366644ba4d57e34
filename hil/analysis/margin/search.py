"""The timing margin k*: the smallest scale of the replayed timing at which a limit breaks
(docs/margin.md, "k*": the loops of a probe, the bracket, the bisection).

A probe at scale k (:func:`hil.analysis.margin.timing.scaled`) runs ``seeds`` loops on the batch
path (:mod:`hil.sim.adversary.loop`), under the scenario's own disturbance or, ``worst``, the worst
one searched; it *breaks* when any loop exceeds a limit of (2) (or the late position error exceeds
``error_bound``). k* is the broken end of the bracket narrowed to ``rel_tol``. Breaking need
not be monotone in k for a nonlinear loop: the probes are all in the record.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller_service.certificate import critical_age
from controller_service.laws.guard import LawFaultError
from hil.analysis.margin.record import MarginProbe, MarginRecord
from hil.analysis.margin.timing import BaseTiming, scaled
from hil.errors import BadInputError
from hil.law.batch import for_batch
from hil.law.facts import Law
from hil.scenario import Scenario, build_loop
from hil.sim.adversary.loop import initial_states, run_loops
from hil.sim.adversary.search import LIMIT_NAMES, scores, worst_disturbance
from plant_emulator.dynamics import VIOLATION_RTOL

SPREAD = 0.01  # m, rad, m/s, rad/s: how far the other seeds' initial states are moved


@dataclass(frozen=True)
class MarginOptions:
    seeds: int = 32
    duration: float = 20.0
    worst: bool = False
    error_bound: float | None = None
    rounds: int = 3
    k_min: float = 1.0 / 8.0  # below it a shorter period costs more than it tells
    k_max: float = 64.0
    rel_tol: float = 0.02


def probe(
    scenario: Scenario, base: BaseTiming, k: float, opts: MarginOptions, loop: Any
) -> tuple[MarginProbe, int]:
    """One scale: the worst score over the loops, and how many loops ran; a law that cannot
    run on arrays (the batch path) is bad input, named."""
    sc, schedule = scaled(scenario, base, k, opts.seeds, opts.duration)
    init = initial_states(sc, opts.seeds, SPREAD, 0)
    age = schedule.max_age()
    try:
        if opts.worst:
            bound, rounds = opts.error_bound, opts.rounds
            best = worst_disturbance(
                sc, schedule, init, rounds=rounds, error_bound=bound, stop_on_break=True, loop=loop
            )
            found = MarginProbe(k, best.score, best.limit, best.broke, age, best.describe())
            return found, best.loops
        modes = np.zeros((opts.seeds, 2, 1), dtype=np.int8)
        seeds = scenario.disturbance.seed + np.arange(opts.seeds, dtype=np.int64)
        peaks = run_loops(sc, schedule, modes, init, loop=loop, own_seeds=seeds)
    except (BadInputError, LawFaultError):
        raise
    except Exception as exc:  # the law may be the user's: whatever it raises on arrays
        law = scenario.controller.get("law", "unified")
        raise BadInputError(
            f"[controller] law {law!r} failed on the batch path (numpy arrays of "
            f"{opts.seeds} robots): {type(exc).__name__}: {exc}"
        ) from exc
    score, which = scores(peaks, sc.limits, opts.error_bound)
    i = int(np.argmax(score))
    broke = bool(score[i] > 1.0 + VIOLATION_RTOL)
    return MarginProbe(k, float(score[i]), LIMIT_NAMES[which[i]], broke, age), opts.seeds


def _bracket(test: Callable[[float], bool], opts: MarginOptions) -> tuple[float | None, float]:
    """(held, broke) scales around the break, doubling or halving from k = 1; held is None
    when even k_min breaks, broke is inf when even k_max holds."""
    if test(1.0):
        hi, lo = 1.0, 0.5
        while test(lo):
            hi, lo = lo, lo / 2.0
            if lo < opts.k_min:
                return None, hi
        return lo, hi
    lo, hi = 1.0, 2.0
    while not test(hi):
        lo, hi = hi, hi * 2.0
        if hi > opts.k_max:
            return lo, math.inf
    return lo, hi


def find_margin(
    scenario: Scenario,
    base: BaseTiming,
    opts: MarginOptions,
    progress: Callable[[MarginProbe], None] | None = None,
) -> MarginRecord:
    """k* for the scenario's law over the base timing (module doc); a law that fails (its
    guard: raises, returns the wrong type or a non-finite torque) ends the search, and the
    record says so (``law_fault``) instead of a k*."""
    started = time.perf_counter()
    built = build_loop(scenario)
    # A law that takes only floats runs one robot at a time (hil.law.batch), as in hil sweep.
    loop = (for_batch(built[0], scenario, built[1]), built[1], built[2])
    probes: list[MarginProbe] = []
    loops = 0

    def test(k: float) -> bool:
        nonlocal loops
        p, n = probe(scenario, base, k, opts, loop)
        probes.append(p)
        loops += n
        if progress is not None:
            progress(p)
        return p.broke

    fault = None
    try:
        if getattr(loop[0], "probe_fault", None) is not None:  # it failed on one robot, at t = 0
            raise LawFaultError(loop[0].probe_fault)
        lo, hi = _bracket(test, opts)
        while lo is not None and math.isfinite(hi) and hi / lo > 1.0 + opts.rel_tol:
            mid = math.sqrt(lo * hi)
            if test(mid):
                hi = mid
            else:
                lo = mid
    except LawFaultError as exc:
        fault, lo, hi = exc.fault, None, math.inf
    broke = {p.k: p for p in probes}.get(hi)
    _, replay = scaled(scenario, base, 1.0, opts.seeds, opts.duration)
    controller, _ref, context = built
    params = getattr(controller, "params", None)  # D*: the certificate's, for a unified law
    d_star = None
    if params is not None and Law.of(scenario.controller).has_certificate:
        ini = scenario.initial
        d_star = critical_age(params, context, params.eps1 is not None, v0=ini.v, w0=ini.omega)
    return MarginRecord(
        source=base.source,
        law=str(scenario.controller.get("law", "unified")),
        disturbance="worst" if opts.worst else "scenario",
        seeds=opts.seeds,
        duration_s=opts.duration,
        k_star=None if broke is None else hi,
        k_held=lo,
        first_broken=None if broke is None else broke.limit,
        disturbance_at_break=None if broke is None else broke.disturbance,
        d_measured_s=base.measured_d_s,
        d_replay_s=replay.max_age(),
        age_at_break_s=None if broke is None else broke.age_s,
        d_star_s=d_star,
        error_bound_m=opts.error_bound,
        loops=loops,
        elapsed_s=time.perf_counter() - started,
        probes=tuple(probes),
        law_fault=None if fault is None else fault.to_dict(),
    )

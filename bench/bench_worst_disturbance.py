"""Where (2) first breaks: random disturbances against the searched worst disturbance.

At a fixed Ts the command delay is bisected for the smallest delay at which some loop breaks a
limit of (2), once under the scenario's random disturbance (uniform in [-s, s], held 0.1 s, one
seed per loop) and once under the worst disturbance searched by :mod:`hil.sim.adversary` (the same
number of loops, the same initial states), and both are compared with the certificate's D*.

Set-ups (``--setup``): ``paper`` is Section 4 of the paper (Table 1 gains, its circle, its start,
Ts = 1 ms) with disturbance bounds s1 = 0.05, s2 = 0.5, the largest round ones with which
Table 1's rho = 1 still meets (12); ``montecarlo`` is tests/test_certified_bound_montecarlo.py's
(rho = 0.5, s1 = 0.3, s2 = 3, Ts = 20 ms).

    python bench/bench_worst_disturbance.py                    # paper set-up, 240 loops a probe
    python bench/bench_worst_disturbance.py --setup montecarlo --loops 1000
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import _here  # noqa: F401  (this checkout first on sys.path)

from controller_service.certificate import critical_age
from hil.scenario import build_loop, loads_scenario
from hil.sim import RobotVariation, simulate_batch
from hil.sim.adversary import scenario_schedule, worst_disturbance
from hil.sim.adversary.loop import initial_states
from plant_emulator.dynamics import VIOLATION_RTOL
from tests.scenario_text import NEAR, circle

SETUPS = {
    "paper": ("1.0", 0.05, 0.5, 0.001, 4.0),
    "montecarlo": ("0.5", 0.3, 3.0, 0.02, 4.0),
}

ROUNDS = 3
SPREAD = 0.3


def _at(sc, delay: float):
    return dataclasses.replace(sc, timing=dataclasses.replace(sc.timing, delay=delay))


def random_score(sc, n: int) -> float:
    init = initial_states(sc, n, SPREAD, 1)
    variations = [
        RobotVariation(
            x=init.x[i],
            y=init.y[i],
            theta=init.theta[i],
            v=init.v[i],
            omega=init.omega[i],
            disturbance_seed=i,
        )
        for i in range(n)
    ]
    out = simulate_batch(sc, variations).summaries
    lim = sc.limits
    return max(max(s["max_abs_v"] / lim.phi1, s["max_abs_omega"] / lim.phi2) for s in out)


def worst_score(sc, n: int) -> tuple[float, str]:
    per_round = max(1, n // ROUNDS)
    best = worst_disturbance(
        sc,
        scenario_schedule(sc, per_round),
        initial_states(sc, per_round, SPREAD, 1),
        rounds=ROUNDS,
        stop_on_break=True,
    )
    return best.score, best.describe()


def bisect_break(score, lo: float, hi: float, tol: float) -> tuple[float | None, list]:
    """The smallest delay in [lo, hi] (to tol) at which score > 1, None if hi holds."""
    probes = []
    s_hi = score(hi)
    probes.append((hi, s_hi))
    if s_hi <= 1.0 + VIOLATION_RTOL:
        return None, probes
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        s = score(mid)
        probes.append((mid, s))
        if s > 1.0 + VIOLATION_RTOL:
            hi = mid
        else:
            lo = mid
    return hi, probes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setup", choices=sorted(SETUPS), default="paper")
    ap.add_argument("--loops", type=int, default=240, help="loops per probe (each method)")
    ap.add_argument("--max-delay", type=float, default=0.3)
    ap.add_argument("--tol", type=float, default=0.002)
    args = ap.parse_args()
    rho, s1, s2, ts, duration = SETUPS[args.setup]
    sc = loads_scenario(
        circle(
            NEAR,
            controller={"law": "unified", "rho": float(rho)},
            disturbance={"kind": "random", "s1": s1, "s2": s2, "period": 0.1},
            timing={"ts": ts},
            run={"duration": duration},
        )
    )
    controller, _ref, context = build_loop(sc)
    d_star = critical_age(controller.params, context, False)
    t0 = time.perf_counter()
    rand, rand_probes = bisect_break(
        lambda d: random_score(_at(sc, d), args.loops), 0.0, args.max_delay, args.tol
    )
    t1 = time.perf_counter()
    worst, worst_probes = bisect_break(
        lambda d: worst_score(_at(sc, d), args.loops)[0], 0.0, args.max_delay, args.tol
    )
    t2 = time.perf_counter()
    pattern = worst_score(_at(sc, worst), args.loops)[1] if worst is not None else None
    age = lambda d: None if d is None else ts + d  # noqa: E731
    out = {
        "setup": args.setup,
        "ts": ts,
        "s1": s1,
        "s2": s2,
        "rho": float(rho),
        "loops_per_probe": args.loops,
        "d_star_s": d_star,
        "break_delay_random_s": rand,
        "break_delay_worst_s": worst,
        "break_age_random_s": age(rand),
        "break_age_worst_s": age(worst),
        "ratio_worst_break_to_d_star": None if worst is None else (ts + worst) / d_star,
        "worst_pattern_at_break": pattern,
        "probes_random": rand_probes,
        "probes_worst": worst_probes,
        "elapsed_random_s": t1 - t0,
        "elapsed_worst_s": t2 - t1,
    }
    print(json.dumps(out, indent=2, default=float))
    if rand is not None and worst is not None:
        print(
            f"break at delay {worst * 1e3:.1f} ms (worst) vs {rand * 1e3:.1f} ms (random), "
            f"Ts = {ts * 1e3:g} ms; D* = {d_star * 1e3:.2f} ms"
        )


if __name__ == "__main__":
    main()

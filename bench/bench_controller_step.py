"""One unified-law update on the real-time (plain float) path: median and p99 per call, and
the ratio to the same equations written straight in one plain function (measured in the same run).

Usage: python bench/bench_controller_step.py [--quick] [--repeats N] [--calls N] [--law NAME]

Each repeat times ``calls`` consecutive updates with time.perf_counter_ns around every call,
over a slowly moving state so the branches vary; the JSON line reports the median over repeats
of each repeat's median and p99 (microseconds) against the 30 us p99 budget (3% of 1 ms).

The baseline (``plain_unified`` below, for law = "unified"): (4)-(10) and the memory rule in
one function on plain floats with the law's outputs (torques, the telemetry dict, the memory
at t + dt) and its bad-input check, nothing else, returning them as the Controller protocol
does (a ControlOutput and a memory NamedTuple, ``ratio_to_plain``) and as bare tuples
(``ratio_to_bare_plain``: what the protocol's two NamedTuples cost on top). Each repeat runs
the same ``calls`` inputs through the law and the baselines back to back, each as one loop
timed on the thread's CPU clock (no clock per call, so the clock's own ~0.1 us does not dilute
the ratio, and time the thread spends descheduled on a shared machine does not count); the
ratios are medians over repeats of law / baseline. Target: ratio_to_plain <= 1.2.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from math import cos, exp, sin, sqrt, tanh
from typing import Any

import _here  # noqa: F401  (this checkout first on sys.path)

from controller_service.laws.base import ControlOutput, DesignContext, RobotState
from controller_service.laws.unified import UnifiedMemory
from controller_service.references import Circle
from controller_service.registry import build_controller

BUDGET_P99_US = 30.0
TARGET_RATIO = 1.2
_new = tuple.__new__  # the fastest way to build a NamedTuple (the law uses it too)


def plain_unified(t, dt, state, ref, memory, k, bare):  # type: ignore[no-untyped-def]
    """The baseline: the unified law (10) written straight, constants ``k`` = (lam, rho, m1,
    m2, l1 / 2, l2 / 2, varpi1, varpi2); ``bare``: bare tuples out instead of the protocol's."""
    lam, rho, m1, m2, hl1, hl2, varpi1, varpi2 = k
    x, y, th, v, w = state
    xd, yd, thd, vd, wd = ref[:5]
    eta, z1, z2 = memory
    c = cos(th)
    s = sin(th)
    dx = x - xd
    dy = y - yd
    xe = c * dx + s * dy
    ye = c * dy - s * dx
    the = th - thd
    r = sqrt(1.0 + xe * xe + ye * ye)
    tr = tanh(r - 1.0)
    st = sin(t)
    xi = eta * rho * tr * st
    q = vd * vd + wd * wd
    g = (xe * (v - vd * cos(the)) + ye * vd * sin(the)) / r
    dxi = eta * rho * (st * (1.0 - tr * tr) * g + cos(t) * tr) - q * xi
    half = 0.5 * (the + xi)
    alpha_v = vd * cos(xi) - z1
    alpha_w = dxi + wd - (lam * vd / r) * (xe * sin(half) + ye * cos(half)) - z2
    v_tilde = v - alpha_v
    w_tilde = w - alpha_w
    tau1 = -varpi1 if v_tilde > 0.0 else (varpi1 if v_tilde < 0.0 else 0.0)
    tau2 = -varpi2 if w_tilde > 0.0 else (varpi2 if w_tilde < 0.0 else 0.0)
    z1n = z1 + dt * hl1 * (xe / r - z1 / m1)
    z2n = z2 + dt * hl2 * (sin(0.5 * (the - xi)) - z2 / m2)
    z1n = -m1 if z1n < -m1 else (m1 if z1n > m1 else z1n)
    z2n = -m2 if z2n < -m2 else (m2 if z2n > m2 else z2n)
    eta_n = eta * exp(-q * dt)
    total = t + dt + xe + ye + v_tilde + w_tilde + eta_n + z1n + z2n
    if total - total != 0.0:
        return (0.0, 0.0, {}), memory
    telemetry = {
        "xe": xe,
        "ye": ye,
        "theta_e": the,
        "xi": xi,
        "v_tilde": v_tilde,
        "w_tilde": w_tilde,
        "z1": z1,
        "z2": z2,
        "eta": eta,
        "alpha_v": alpha_v,
        "alpha_w": alpha_w,
        "nonfinite": 0.0,
    }
    if bare:
        return (tau1, tau2, telemetry), (eta_n, z1n, z2n)
    return _new(ControlOutput, (tau1, tau2, telemetry)), _new(UnifiedMemory, (eta_n, z1n, z2n))


def _inputs(calls: int) -> tuple[list, list]:
    reference = Circle()
    refs = [reference.sample(k * 1e-3) for k in range(calls)]
    states = [
        RobotState(0.3 * math.sin(k * 1e-3), -1.0 + 1e-5 * k, 0.1, 0.4, 0.2 * math.cos(k * 1e-2))
        for k in range(calls)
    ]
    return refs, states


def loop_pair(controller: Any, calls: int) -> tuple[float, float, float]:
    """CPU microseconds per call of the law, of :func:`plain_unified` with the protocol's
    outputs and with bare tuples, on the same inputs, each as one timed loop."""
    refs, states = _inputs(calls)
    params, limits = controller.params, controller.context.limits
    k_plain = (
        *(float(q) for q in (params.lam, params.rho, params.m1, params.m2)),
        0.5 * params.l1,
        0.5 * params.l2,
        float(limits.varpi1),
        float(limits.varpi2),
    )
    update = controller.update
    clock = time.thread_time_ns
    memory = controller.initial_memory()
    start = clock()
    for k in range(calls):
        _, memory = update(k * 1e-3, 1e-3, states[k], refs[k], memory)
    law_us = (clock() - start) / 1e3 / calls
    plain_us = []
    for bare in (False, True):
        memory_p = controller.initial_memory()
        start = clock()
        for k in range(calls):
            _, memory_p = plain_unified(k * 1e-3, 1e-3, states[k], refs[k], memory_p, k_plain, bare)
        plain_us.append((clock() - start) / 1e3 / calls)
        # Same equations, same inputs: the memories agree (else the baseline is not the law).
        assert all(abs(a - b) <= 1e-9 for a, b in zip(memory, memory_p, strict=True))
    return law_us, plain_us[0], plain_us[1]


def one_repeat(law: str, calls: int) -> tuple[float, float]:
    controller = build_controller({"law": law}, DesignContext())
    memory = controller.initial_memory()
    refs, states = _inputs(calls)
    samples = [0] * calls
    clock = time.perf_counter_ns
    update = controller.update
    for k in range(calls):
        start = clock()
        _, memory = update(k * 1e-3, 1e-3, states[k], refs[k], memory)
        samples[k] = clock() - start
    samples.sort()
    return samples[calls // 2] / 1e3, samples[min(calls - 1, int(0.99 * calls))] / 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 repeats of 2,000 calls")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--calls", type=int, default=10_000)
    parser.add_argument("--law", default="unified")
    args = parser.parse_args()
    repeats, calls = (5, 2_000) if args.quick else (args.repeats, args.calls)
    one_repeat(args.law, 500)  # warm-up
    results = [one_repeat(args.law, calls) for _ in range(repeats)]
    p50 = statistics.median(r[0] for r in results)
    p99 = statistics.median(r[1] for r in results)
    plain: dict[str, Any] = {}
    if args.law == "unified":
        controller = build_controller({"law": "unified"}, DesignContext())
        loop_pair(controller, 500)  # warm-up
        pairs = [loop_pair(controller, calls) for _ in range(repeats)]
        ratio = statistics.median(a / b for a, b, _ in pairs)
        plain = {
            "loop_law_cpu_us": round(statistics.median(a for a, _, _ in pairs), 3),
            "loop_plain_cpu_us": round(statistics.median(b for _, b, _ in pairs), 3),
            "loop_bare_plain_cpu_us": round(statistics.median(c for _, _, c in pairs), 3),
            "ratio_to_plain": round(ratio, 3),
            "ratio_to_bare_plain": round(statistics.median(a / c for a, _, c in pairs), 3),
            "target_ratio": TARGET_RATIO,
            "ratio_met": ratio <= TARGET_RATIO,
        }
    print(
        json.dumps(
            {
                "bench": "controller_step",
                "law": args.law,
                "path": "float",
                "repeats": repeats,
                "calls_per_repeat": calls,
                "median_us": round(p50, 3),
                "p99_us": round(p99, 3),
                "worst_repeat_p99_us": round(max(r[1] for r in results), 3),
                "budget_p99_us": BUDGET_P99_US,
                "within_budget": p99 <= BUDGET_P99_US,
                **plain,
                "python": platform.python_version(),
                "machine": platform.machine(),
            }
        )
    )


if __name__ == "__main__":
    main()

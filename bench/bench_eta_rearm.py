"""Stabilization after tracking, with and without the eta re-arm (docs/laws.md, "eta re-arm").

The bundled circle_then_stop with the stop at 60 s (then its 5 s ramp) and 30 s at rest, each
law in one batch run of 8 robots on the batch path: the bundled initial pose and 7 others within
0.3 m and 0.3 rad of it (seeded, the poses of tests/test_law_eta_rearm.py). Three laws: the
paper's (no re-arm), the eta-only re-arm, and the re-arm with kick and align
(``eta_rearm_dwell = 2``, ``eta_rearm_tol = 0.03``). For each robot: the position and heading
errors when the reference comes to rest, 30 s later, and their largest values over the last 2 s
of the 30 (the sampled sign law keeps both in a limit cycle, so one instant can flatter); the
time after which both stay below 0.05 ("settled", "-" if they do not by the end); the resets;
whether the limits (2) held over the whole run.

Then the paper's law and the re-arm with kick and align at rest from the start (the bundled
stabilization task, eta(0) = 1) from N random offsets of 0.1 to 0.4 m in any direction, heading
+-0.3 rad (seeded): how many meet the position target, and both targets, over the last 2 s of 30.

    python bench/bench_eta_rearm.py                # Ts = 5 ms (tests/test_law_eta_rearm.py)
    python bench/bench_eta_rearm.py --ts 0.01      # the heading limit cycle is too wide
    python bench/bench_eta_rearm.py --ts 0.001     # the paper's Ts
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import _here  # noqa: F401  (this checkout first on sys.path)
import numpy as np

from hil.bundled import resolve_scenario
from hil.scenario import load_scenario
from hil.sim import simulate_batch
from hil.sim.core import RobotVariation

STOP = 60.0
RAMP = 5.0  # the bundled stop's ramp (k1 = 0.1, k2 = 0.04)
AFTER = 30.0
WINDOW = 2.0  # s at the end of AFTER over which the largest errors are taken
TARGET = 0.05  # m and rad
LAWS: dict[str, dict[str, Any]] = {
    "paper": {},
    "eta_rearm": {"eta_rearm": True},
    "kick_align": {"eta_rearm": True, "eta_rearm_dwell": 2.0, "eta_rearm_tol": 0.03},
}


def _poses(sc: Any) -> list[RobotVariation]:
    base = np.array([sc.initial.x, sc.initial.y, sc.initial.theta])
    moves = np.vstack([np.zeros(3), np.random.default_rng(5).uniform(-0.3, 0.3, (7, 3))])
    return [RobotVariation(*(base + d)) for d in moves]


def _ends(trace: np.ndarray, cols: list[str], rest: float) -> dict[str, Any]:
    t = trace[:, cols.index("t")]
    pos = trace[:, cols.index("position_error")]
    head = np.abs(trace[:, cols.index("heading_error")])
    at = min(int(np.searchsorted(t, rest - 1e-9)), len(t) - 1)
    last = t >= rest + AFTER - WINDOW
    out = np.nonzero((pos >= TARGET) | (head >= TARGET))[0]
    if len(out) and out[-1] == len(t) - 1:
        settled: Any = "-"  # not within target at the end
    else:  # the first time from which both stay within target (0: already at rest)
        settled = max(0.0, float(t[out[-1] + 1] - rest)) if len(out) else 0.0
    resets = int(trace[:, cols.index("eta_rearmed")].sum()) if "eta_rearmed" in cols else 0
    return {
        "rest": (pos[at], head[at]),
        "+30s": (pos[-1], head[-1]),
        "last": (pos[last].max(), head[last].max()),
        "settled": settled,
        "resets": resets,
    }


def circle_then_stop(ts: float, name: str) -> list[dict[str, Any]]:
    sc = load_scenario(resolve_scenario("paper_circle_then_stop_unified"))
    sc = dataclasses.replace(
        sc,
        controller={**sc.controller, **LAWS[name]},
        reference={**sc.reference, "stop_time": STOP},
        timing=dataclasses.replace(sc.timing, ts=ts),
        run=dataclasses.replace(sc.run, duration=STOP + RAMP + AFTER),
    )
    robots = _poses(sc)
    res = simulate_batch(sc, robots, record=list(range(len(robots))))
    rows = []
    for i in range(len(robots)):
        row = _ends(res.traces[i], res.columns, STOP + RAMP)
        row["held"] = res.summaries[i]["limits_held"]
        rows.append(row)
    return rows


def offsets_at_rest(ts: float, name: str, n: int) -> dict[str, Any]:
    rng = np.random.default_rng(11)
    size, angle, heading = (
        rng.uniform(0.1, 0.4, n),
        rng.uniform(0, 2 * np.pi, n),
        rng.uniform(-0.3, 0.3, n),
    )
    robots = [
        RobotVariation(x=float(s * np.cos(a)), y=float(s * np.sin(a)), theta=float(h))
        for s, a, h in zip(size, angle, heading, strict=True)
    ]
    sc = load_scenario(resolve_scenario("paper_stabilization"))
    sc = dataclasses.replace(
        sc,
        controller={**sc.controller, **LAWS[name]},
        timing=dataclasses.replace(sc.timing, ts=ts),
        run=dataclasses.replace(sc.run, duration=AFTER),
    )
    res = simulate_batch(sc, robots, record=list(range(n)))
    last = np.array([_ends(res.traces[i], res.columns, 0.0)["last"] for i in range(n)])
    return {
        "position": int(np.sum(last[:, 0] < TARGET)),
        "both": int(np.sum((last[:, 0] < TARGET) & (last[:, 1] < TARGET))),
        "held": all(s["limits_held"] for s in res.summaries),
    }


def _pair(value: tuple[float, float]) -> str:
    return f"{value[0]:.4f} m, {value[1]:.4f} rad"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ts", type=float, default=0.005)
    ap.add_argument("--offsets", type=int, default=50, help="random offsets at rest (0: none)")
    args = ap.parse_args()
    print(
        f"## circle_then_stop, stop at {STOP:g} s, Ts = {args.ts * 1e3:g} ms, {AFTER:g} s at rest\n"
    )
    print("| law | robot | at rest | +30 s | last 2 s | settled (s) | resets | limits held |")
    print("|---|---|---|---|---|---|---|---|")
    for name in LAWS:
        rows = circle_then_stop(args.ts, name)
        for i, row in enumerate(rows):
            settled = row["settled"] if row["settled"] == "-" else f"{row['settled']:.1f}"
            cells = [_pair(row[k]) for k in ("rest", "+30s", "last")]
            cells += [settled, str(row["resets"]), str(row["held"])]
            print(f"| {name} | {i} | {' | '.join(cells)} |")
        worst = {
            k: tuple(np.max([row[k] for row in rows], axis=0)) for k in ("rest", "+30s", "last")
        }
        times = [row["settled"] for row in rows]
        settled = "-" if "-" in times else f"{max(times):.1f}"
        held = all(row["held"] for row in rows)
        cells = [_pair(worst[k]) for k in ("rest", "+30s", "last")]
        print(f"| **{name}** | **max** | {' | '.join(cells)} | {settled} | - | {held} |")
    if args.offsets:
        n = args.offsets
        print(
            f"\n## at rest from {n} random offsets of 0.1-0.4 m, heading +-0.3 rad, {AFTER:g} s\n"
        )
        print("| law | position < 0.05 m | both < 0.05 | limits held |")
        print("|---|---|---|---|")
        for name in ("paper", "kick_align"):
            out = offsets_at_rest(args.ts, name, n)
            print(f"| {name} | {out['position']}/{n} | {out['both']}/{n} | {out['held']} |")


if __name__ == "__main__":
    main()

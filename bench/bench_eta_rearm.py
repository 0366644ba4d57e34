"""Stabilization after tracking, with and without the eta re-arm (docs/laws.md, "eta re-arm").

The bundled circle_then_stop with the stop at 60 s (then its 5 s ramp), on the batch path, for
three laws: the paper's (no re-arm), the eta-only re-arm, and the re-arm with the kick
(``eta_rearm_tol``). For each: the position and heading errors when the reference comes to rest
and 10, 20, 30 s later, their largest values over the last 2 s of the 30 s (the sign law at
Ts = 10 ms keeps the heading in a limit cycle, so one instant can flatter it), whether the
limits (2) held over the whole run, the number of resets, and eta at the end.

Then the same three laws at rest from the start (the bundled stabilization task, eta(0) = 1)
from a pure lateral offset of 0.28 m, the error the 10 ms tracking leaves at the stop: at the
paper's Ts = 1 ms the tracking leaves almost nothing to stabilize, so this is where the rule is
seen at that Ts.

    python bench/bench_eta_rearm.py              # Ts = 10 ms (tests/test_law_eta_rearm.py)
    python bench/bench_eta_rearm.py --ts 0.001   # the paper's Ts
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from typing import Any

import _here  # noqa: F401  (this checkout first on sys.path)
import numpy as np

from hil.bundled import resolve_scenario
from hil.scenario import load_scenario
from hil.sim import simulate_batch

STOP = 60.0
RAMP = 5.0
AFTER = 30.0
WINDOW = 2.0  # s at the end of AFTER over which the largest errors are taken
LAWS: dict[str, dict[str, Any]] = {
    "paper": {},
    "eta_rearm": {"eta_rearm": True},
    "eta_rearm_kick": {"eta_rearm": True, "eta_rearm_dwell": 8.0, "eta_rearm_tol": 0.02},
}


OFFSET = 0.28  # m, lateral, for the runs at rest from the start


def run(ts: float, name: str, at_rest: bool = False) -> dict[str, object]:
    rest = 0.0 if at_rest else STOP + RAMP
    if at_rest:
        sc = load_scenario(resolve_scenario("paper_stabilization"))
        sc = dataclasses.replace(sc, initial=dataclasses.replace(sc.initial, x=0.0, y=OFFSET))
    else:
        sc = load_scenario(resolve_scenario("paper_circle_then_stop_unified"))
        sc = dataclasses.replace(sc, reference={**sc.reference, "stop_time": STOP})
    sc = dataclasses.replace(
        sc,
        controller={**sc.controller, **LAWS[name]},
        timing=dataclasses.replace(sc.timing, ts=ts),
        run=dataclasses.replace(sc.run, duration=rest + AFTER),
    )
    res = simulate_batch(sc, 1, record=[0])
    tr, cols = res.traces[0], res.columns
    t = tr[:, cols.index("t")]
    pos = tr[:, cols.index("position_error")]
    head = np.abs(tr[:, cols.index("heading_error")])
    out: dict[str, object] = {"law": name, "controller": LAWS[name]}
    out["limits_held"] = res.summaries[0]["limits_held"]
    for after in (0.0, 10.0, 20.0, AFTER):
        i = min(int(np.searchsorted(t, rest + after)), len(t) - 1)
        out[f"+{after:g}s"] = {
            "position_error_m": round(float(pos[i]), 4),
            "heading_error_rad": round(float(head[i]), 4),
        }
    last = t >= rest + AFTER - WINDOW
    out[f"max over the last {WINDOW:g}s"] = {
        "position_error_m": round(float(pos[last].max()), 4),
        "heading_error_rad": round(float(head[last].max()), 4),
    }
    if "eta_rearmed" in cols:
        out["resets"] = int(tr[:, cols.index("eta_rearmed")].sum())
    out["eta_end"] = float(tr[-1, cols.index("eta")])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ts", type=float, default=0.01)
    args = ap.parse_args()
    out = {
        "ts": args.ts,
        "circle_then_stop": [run(args.ts, name) for name in LAWS],
        f"at_rest_from_{OFFSET:g}_m": [run(args.ts, name, at_rest=True) for name in LAWS],
    }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()

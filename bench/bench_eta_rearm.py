"""Stabilization after tracking, with and without the eta re-arm (docs/laws.md, "eta re-arm").

The bundled circle_then_stop with the stop at 60 s (then its 5 s ramp), on the batch path; for
each law: the position and heading errors when the reference comes to rest and 10, 20, 30 s
later, and eta at the end.

    python bench/bench_eta_rearm.py              # Ts = 10 ms (tests/test_law_eta_rearm.py)
    python bench/bench_eta_rearm.py --ts 0.001   # the paper's Ts
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import _here  # noqa: F401  (this checkout first on sys.path)
import numpy as np

from hil.bundled import resolve_scenario
from hil.scenario import load_scenario
from hil.sim import simulate_batch

STOP = 60.0
RAMP = 5.0
AFTER = 30.0


def run(ts: float, rearm: bool) -> dict[str, object]:
    sc = load_scenario(resolve_scenario("paper_circle_then_stop_unified"))
    sc = dataclasses.replace(
        sc,
        controller={**sc.controller, **({"eta_rearm": True} if rearm else {})},
        reference={**sc.reference, "stop_time": STOP},
        timing=dataclasses.replace(sc.timing, ts=ts),
        run=dataclasses.replace(sc.run, duration=STOP + RAMP + AFTER),
    )
    res = simulate_batch(sc, 1, record=[0])
    tr, cols = res.traces[0], res.columns
    t = tr[:, cols.index("t")]
    out: dict[str, object] = {"eta_rearm": rearm, "limits_held": res.summaries[0]["limits_held"]}
    for after in (0.0, 10.0, 20.0, AFTER):
        i = min(int(np.searchsorted(t, STOP + RAMP + after)), len(t) - 1)
        out[f"+{after:g}s"] = {
            "position_error_m": float(tr[i, cols.index("position_error")]),
            "heading_error_rad": float(abs(tr[i, cols.index("heading_error")])),
        }
    out["eta_end"] = float(tr[-1, cols.index("eta")])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ts", type=float, default=0.01)
    args = ap.parse_args()
    print(json.dumps({"ts": args.ts, "runs": [run(args.ts, r) for r in (False, True)]}, indent=2))


if __name__ == "__main__":
    main()

"""The clock offset estimate against the lab's injected offsets: its error, per host, as the
median of repeated rounds, for the probe's bursts and for single pings (docs/clocks.md).

Builds a lab of three hosts (root) with CLOCK_MONOTONIC offsets +3.2 s, -1.7 s and +0.9 s, runs
the clock echo on h1, and per round probes it from h2, h3 and h1 (same host) in two ways:

- ``burst``: ``python -m runtime.clocksync probe`` (40 exchanges in bursts of four, what every
  service does);
- ``single``: 40 lone exchanges 20 ms apart through the same filter (the probe before bursts),
  the baseline measured in the same run.

Each round's figure is the estimate minus the injected offset (plant minus probe) and the
estimate's stated uncertainty. The budget is an error within 200 us, quoted as the median of
the rounds per host.

    python bench/bench_clock_offsets.py               # 5 rounds
    python bench/bench_clock_offsets.py --rounds 9
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import _here  # noqa: F401  (this checkout first on sys.path)

from tests.lab_helpers import ROOT, hil, lab_argv, lab_skip_reason

LAB = "bclk"
OFFSETS = {"h1": 3.2, "h2": -1.7, "h3": 0.9}
ROUTER = "tcp/127.0.0.1:7447"
BUDGET_US = 200.0
EXCHANGES = 40
SINGLE = f"""
import json, time
from runtime.clocksync import ClockProbe
from runtime.zsession import open_session
s = open_session({ROUTER!r}, mode="client", credentials=None)
p = ClockProbe(s, "r1", interval=0.02)
while p.exchanges < {EXCHANGES}:
    ex = p.exchange()
    if ex is not None:
        p.record(ex)
    time.sleep(p.interval)
e = p.estimate
print(json.dumps({{"offset_ns": e.offset_ns, "uncertainty_ns": e.uncertainty_ns}}))
s.close()
"""
MODES = {
    "burst": ["-m", "runtime.clocksync", "probe", "r1", ROUTER, str(EXCHANGES)],
    "single": ["-c", SINGLE],
}


def probe(host: str, mode: str, env: dict) -> tuple[float, float]:
    """(error, uncertainty) in microseconds of one probe from ``host``."""
    argv = lab_argv(LAB, host, sys.executable, *MODES[mode])
    got = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=60)
    if got.returncode != 0:
        raise SystemExit(f"probe on {host} ({mode}) failed: {got.stderr.strip()}")
    est = json.loads(got.stdout)
    injected = (OFFSETS["h1"] - OFFSETS[host]) * 1e9
    return (est["offset_ns"] - injected) / 1e3, est["uncertainty_ns"] / 1e3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args()
    if (why := lab_skip_reason()) is not None:
        print(f"cannot build a lab here: {why}", file=sys.stderr)
        return 2
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    rows: dict[tuple[str, str], list[tuple[float, float]]] = {}
    up = hil("lab", "up", "--name", LAB, "--hosts", "3",
             *[f"--offset={h}={o}" for h, o in OFFSETS.items()])  # fmt: skip
    if up.returncode != 0:
        print(up.stderr, file=sys.stderr)
        return 2
    echo = None
    try:
        echo = subprocess.Popen(
            lab_argv(LAB, "h1", sys.executable, "-m", "runtime.clocksync", "echo", "r1", ROUTER),
            env=env, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert echo.stdout is not None
        if echo.stdout.readline().strip() != "echo up":
            raise SystemExit("the clock echo did not start")
        time.sleep(0.3)  # the other routers learn of the echo's subscriber
        for i in range(a.rounds):
            for host in ("h2", "h3", "h1"):
                for mode in MODES:
                    err, unc = probe(host, mode, env)
                    rows.setdefault((host, mode), []).append((err, unc))
                    print(json.dumps({"round": i, "host": host, "mode": mode,
                                      "error_us": round(err, 1), "uncertainty_us": round(unc, 1)}),
                          flush=True)  # fmt: skip
    finally:
        if echo is not None:
            echo.terminate()
            echo.wait(10)
        hil("lab", "down", "--name", LAB)
    print(f"\n{'host':4} {'mode':6} {'median |error| us':>18} {'max |error| us':>15} "
          f"{'median uncertainty us':>22}  within {BUDGET_US:.0f} us")  # fmt: skip
    for (host, mode), got in rows.items():
        errs = [abs(e) for e, _ in got]
        med = statistics.median(errs)
        unc = statistics.median(u for _, u in got)
        print(f"{host:4} {mode:6} {med:18.1f} {max(errs):15.1f} {unc:22.1f}  "
              f"{'yes' if med <= BUDGET_US else 'NO'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Closed loop over Zenoh at 500 Hz, 1 kHz and 2 kHz, with baselines measured in the same run.

For each rate (``hil run`` of the paper's tracking circle, Zenoh command path, CAN off so the
figures are the Zenoh loop's own) and each trigger mode it reports, as medians of repeats:

- wake-up lateness p50/p99 beside ``cyclictest`` at the same interval and policy
  (target: p99 within 2x of cyclictest's);
- the loop's transport + compute time (State hop plant -> controller, the law's compute,
  command hop controller -> plant; the periodic trigger's wait for its tick excluded) beside a
  raw Zenoh ping-pong RTT between two Python processes (target: p50 within 1.3x of it);
- sample-to-apply latency p50/p99 in both trigger modes (how much the periodic tick adds);
- deadline-miss rate (target < 0.1 % at 1 kHz) and the highest rate meeting it, beside the
  share of samples that got no command and of commands applied more than a period late
  (hil.measure's true counts: a miss skips slots, a late state skips a sample);
- the applied path's command age p50 and max (D) beside D*, the certificate's limit.

    python bench/bench_rt_loop.py            # 30 s per run, 3 repeats
    python bench/bench_rt_loop.py --quick    # 5 s per run, 1 repeat
Prints one JSON object (also written with --out FILE).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

FIFO_SCENARIO = """
[realtime]
scheduling = "fifo"
trigger = "{trigger}"
"""


def run_loop(rate: float, duration: float, trigger: str, tmp: Path) -> dict[str, Any]:
    scen = tmp / f"scen-{trigger}.toml"
    scen.write_text(
        (ROOT / "hil" / "scenarios" / "paper_tracking.toml").read_text()
        + FIFO_SCENARIO.format(trigger=trigger)
    )
    out = tmp / f"run-{rate:g}-{trigger}"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hil",
            "run",
            str(scen),
            "--rate",
            str(rate),
            "--duration",
            str(duration),
            "--cmd-path",
            "zenoh",
            "--no-can",
            "--quiet",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=duration + 180,
    )
    if proc.returncode not in (0, 1):
        raise RuntimeError(proc.stderr[-2000:])
    s = json.loads((out / "summary.json").read_text())
    t = s["timing"]

    def g(fig: str, key: str) -> float | None:
        return (t.get(fig) or {}).get(key)

    return {
        "wakeup_p50_us": g("wakeup_lateness", "p50_us"),
        "wakeup_p99_us": g("wakeup_lateness", "p99_us"),
        "wakeup_max_us": g("wakeup_lateness", "max_us"),
        "skipped_slots": t.get("skipped_slots"),
        "samples_without_command_rate": t.get("samples_without_command_rate"),
        "late_commands_rate": t.get("late_commands_rate"),
        "command_age_p50_us": g("command_age_zenoh", "p50_us"),
        "command_age_max_us": g("command_age_zenoh", "max_us"),
        "d_star_us": ((s.get("certificate") or {}).get("d_star_s") or 0) * 1e6,
        "loop_p50_us": g("loop_transport_compute", "p50_us"),
        "loop_p99_us": g("loop_transport_compute", "p99_us"),
        "compute_p50_us": g("compute", "p50_us"),
        "s2a_p50_us": g("sample_to_apply_zenoh", "p50_us"),
        "s2a_p99_us": g("sample_to_apply_zenoh", "p99_us"),
        "miss_rate": t.get("deadline_miss_rate"),
        "applied": g("sample_to_apply_zenoh", "count"),
        "policy": (s["scheduling"]["controller"] or {}).get("policy"),
    }


RESPONDER = """
import sys, time, zenoh
from runtime.zsession import open_session, publisher
from protocol.zenoh_config import COMMAND_QOS
s = open_session(sys.argv[1])
pub = publisher(s, "bench/pong", COMMAND_QOS)
s.declare_subscriber("bench/ping", lambda m: pub.put(m.payload.to_bytes()))
print("ready", flush=True)
time.sleep(1e9)
"""


def paced_pingpong(rate: float, n: int) -> dict[str, Any]:
    """Zenoh ping-pong between two Python processes, one ping per period (not back to back):
    the threads on both sides go idle between messages, as in the control loop."""
    import queue
    import socket
    import time

    from hil.measure.stats import summarize_ns
    from protocol.zenoh_config import COMMAND_QOS
    from runtime.realtime import wait_until_ns
    from runtime.zsession import open_session, publisher

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        ep = f"tcp/127.0.0.1:{sock.getsockname()[1]}"
    session = open_session(ep, listen_endpoint=True)
    resp = subprocess.Popen([sys.executable, "-c", RESPONDER, ep], stdout=subprocess.PIPE,
                            cwd=ROOT, text=True)  # fmt: skip
    try:
        resp.stdout.readline()
        replies: queue.Queue[int] = queue.Queue()
        session.declare_subscriber("bench/pong", lambda m: replies.put(time.monotonic_ns()))
        pub = publisher(session, "bench/ping", COMMAND_QOS)
        for _ in range(300):  # routes form: ping until answered
            pub.put(b"x" * 64)
            try:
                replies.get(timeout=0.1)
                break
            except queue.Empty:
                continue
        period = round(1e9 / rate)
        start = time.monotonic_ns() + period
        rtts = []
        for k in range(n):
            wait_until_ns(start + k * period)
            t0 = time.monotonic_ns()
            pub.put(b"x" * 64)
            try:
                rtts.append(replies.get(timeout=1.0) - t0)
            except queue.Empty:
                continue
        return summarize_ns(rtts)
    finally:
        resp.kill()
        resp.wait()
        session.close()


def median_of(runs: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k in runs[0]:
        vals = [r[k] for r in runs if isinstance(r[k], int | float)]
        out[k] = statistics.median(vals) if vals else runs[0][k]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0, 2000.0])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="5 s runs, 1 repeat")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    if a.quick:
        a.duration, a.repeats = 5.0, 1
    from bench.cyclictest_baseline import baseline as cyclictest
    from bench.zenoh_pingpong import zenoh_pingpong

    result: dict[str, Any] = {"duration_s": a.duration, "repeats": a.repeats, "rates": {}}
    pp = [zenoh_pingpong(n=2000 if a.quick else 10_000) for _ in range(a.repeats)]
    rtt_p50 = statistics.median(p["rtt_p50_us"] for p in pp)
    result["zenoh_pingpong_rtt_p50_us"] = rtt_p50
    with tempfile.TemporaryDirectory() as tmpd:
        tmp = Path(tmpd)
        for rate in a.rates:
            ct = cyclictest(round(1e6 / rate), min(a.duration, 10.0), a.repeats)["median"]
            per = {}
            for trigger in ("periodic", "on_state"):
                per[trigger] = median_of(
                    [run_loop(rate, a.duration, trigger, tmp) for _ in range(a.repeats)]
                )
            paced = [paced_pingpong(rate, 2000 if a.quick else 10_000) for _ in range(a.repeats)]
            paced_p50 = statistics.median(x["p50_us"] for x in paced)
            p = per["periodic"]
            o = per["on_state"]
            result["rates"][f"{rate:g}"] = {
                "periodic": p,
                "on_state": o,
                "cyclictest_p50_us": ct["p50_us"],
                "cyclictest_p99_us": ct["p99_us"],
                "cyclictest_max_us": ct.get("max_us"),
                "wakeup_p99_ratio_to_cyclictest": (p["wakeup_p99_us"] or 0) / max(ct["p99_us"], 1),
                "loop_p50_ratio_to_pingpong": (o["loop_p50_us"] or 0) / rtt_p50,
                "paced_pingpong_rtt_p50_us": paced_p50,
                "loop_p50_ratio_to_paced_pingpong": (o["loop_p50_us"] or 0) / paced_p50,
                "periodic_adds_to_s2a_p50_us": (p["s2a_p50_us"] or 0) - (o["s2a_p50_us"] or 0),
                "miss_rate_ok": (p["miss_rate"] or 0) < 0.001,
            }
    # The highest rate that meets the target with every lower rate meeting it too: a noisy
    # pass at 2 kHz after a miss at 1 kHz is no evidence that 2 kHz is safe.
    highest = None
    for r in sorted(result["rates"], key=float):
        if not result["rates"][r]["miss_rate_ok"]:
            break
        highest = float(r)
    result["highest_rate_with_miss_rate_below_0.1pct"] = highest
    result["rates_meeting_miss_rate"] = [
        float(r) for r, v in result["rates"].items() if v["miss_rate_ok"]
    ]
    text = json.dumps(result, indent=2)
    print(text)
    if a.out:
        a.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())

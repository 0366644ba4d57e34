"""Closed loop over Zenoh at 500 Hz, 1 kHz and 2 kHz, with baselines measured in the same run.

For each rate (``hil run`` of the paper's tracking circle, Zenoh command path, CAN off so the
figures are the Zenoh loop's own) and each trigger mode it reports, over the repeats, each
p50/p99 as the median of the repeats' own p50/p99 and each maximum, count of misses or skipped
slots and rate of misses as the worst repeat's (one stalled repeat of three shows):

- wake-up lateness p50/p99/max beside ``cyclictest`` at the same interval, policy and CPU
  latency request (``--idle``; target: p99 within 2x of cyclictest's), periodic mode only (n/a
  in on_state);
- the loop's transport + compute time (State hop plant -> controller, the law's compute,
  command hop controller -> plant; the periodic trigger's wait for its tick excluded) beside a
  raw Zenoh ping-pong RTT between two Python processes (target: p50 within 1.3x of it);
- sample-to-apply latency p50/p99 in both trigger modes (how much the periodic tick adds);
- deadline-miss rate, periodic mode only (target < 0.1 % at 1 kHz; n/a in on_state, which has
  no tick to miss) and the highest rate meeting it, beside the
  share of samples that got no command and of commands applied more than a period late
  (hil.analysis.measure's true counts: a miss skips slots, a late state skips a sample);
- the applied path's command age p50 and max (D) beside D*, the certificate's limit.

    python bench/bench_rt_loop.py            # 30 s per run, 3 repeats
    python bench/bench_rt_loop.py --quick    # 5 s per run, 1 repeat
Prints one JSON object (also written with --out FILE). A figure a run's mode measures and its
summary.json lacks fails the benchmark (exit 2, naming the figure, the rate and the mode): it is
never read as 0.
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

from hil.verdict import EXIT_CODE  # noqa: E402 (a verdict's codes: the command worked)
from protocol.settings import IDLE_POLICIES  # noqa: E402 (after the path is set)

FIFO_SCENARIO = """
[realtime]
scheduling = "fifo"
trigger = "{trigger}"
tick_phase = "{tick_phase}"
idle = "{idle}"
"""


def run_loop(
    rate: float,
    duration: float,
    trigger: str,
    tmp: Path,
    tick_phase: str = "half",
    idle: str = "poll",
) -> dict[str, Any]:
    scen = tmp / f"scen-{trigger}.toml"
    scen.write_text(
        (ROOT / "hil" / "scenarios" / "paper_tracking.toml").read_text()
        + FIFO_SCENARIO.format(trigger=trigger, tick_phase=tick_phase, idle=idle)
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
    if proc.returncode not in EXIT_CODE.values():
        raise RuntimeError(proc.stderr[-2000:])
    return figures_of(json.loads((out / "summary.json").read_text()), rate, trigger, out)


class MissingFigureError(RuntimeError):
    """A figure the run's trigger mode measures is not in its summary.json: the benchmark
    fails rather than read it as 0 (a missing miss rate would pass its target)."""


MEDIAN = "median of the repeats"
WORST = "worst repeat"
BOTH = ("periodic", "on_state")
PERIODIC = ("periodic",)
NA = "n/a"  # a figure the trigger mode does not measure (on_state has no tick to be late)

# name: (path in summary.json, trigger modes that must have it, how repeats combine). A
# maximum, a count of misses or skipped slots and a rate of misses keep the worst repeat (one
# stalled repeat of three must show); a p50/p99 is the median of the repeats' own p50/p99.
FIGURES: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    "wakeup_p50_us": (("timing", "wakeup_lateness", "p50_us"), PERIODIC, MEDIAN),
    "wakeup_p99_us": (("timing", "wakeup_lateness", "p99_us"), PERIODIC, MEDIAN),
    "wakeup_max_us": (("timing", "wakeup_lateness", "max_us"), PERIODIC, WORST),
    "deadline_misses": (("timing", "deadline_misses"), PERIODIC, WORST),
    "skipped_slots": (("timing", "skipped_slots"), PERIODIC, WORST),
    "miss_rate": (("timing", "deadline_miss_rate"), PERIODIC, WORST),
    "samples_without_command_rate": (("timing", "samples_without_command_rate"), BOTH, WORST),
    "late_commands_rate": (("timing", "late_commands_rate"), BOTH, WORST),
    "command_age_p50_us": (("timing", "command_age_zenoh", "p50_us"), BOTH, MEDIAN),
    "command_age_max_us": (("timing", "command_age_zenoh", "max_us"), BOTH, WORST),
    "d_star_s": (("certificate", "d_star_s"), BOTH, MEDIAN),
    "loop_p50_us": (("timing", "loop_transport_compute", "p50_us"), BOTH, MEDIAN),
    "loop_p99_us": (("timing", "loop_transport_compute", "p99_us"), BOTH, MEDIAN),
    "loop_max_us": (("timing", "loop_transport_compute", "max_us"), BOTH, WORST),
    "compute_p50_us": (("timing", "compute", "p50_us"), BOTH, MEDIAN),
    "s2a_p50_us": (("timing", "sample_to_apply_zenoh", "p50_us"), BOTH, MEDIAN),
    "s2a_p99_us": (("timing", "sample_to_apply_zenoh", "p99_us"), BOTH, MEDIAN),
    "s2a_max_us": (("timing", "sample_to_apply_zenoh", "max_us"), BOTH, WORST),
    "applied": (("timing", "sample_to_apply_zenoh", "count"), BOTH, MEDIAN),
}
# Shown when the run writes them, required by no mode (the slots of the miss rate's denominator).
OPTIONAL: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    "slots": (("timing", "slots"), PERIODIC, MEDIAN),
}


def _lookup(summary: dict[str, Any], path: tuple[str, ...]) -> Any:
    v: Any = summary
    for key in path:
        v = v.get(key) if isinstance(v, dict) else None
    return v


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def figures_of(summary: dict[str, Any], rate: float, trigger: str, folder: Path) -> dict[str, Any]:
    """The benchmark's figures from one run's summary.json; a figure the mode must have and
    does not raises :class:`MissingFigureError`; one the mode does not measure is ``"n/a"``."""
    out: dict[str, Any] = {}
    for name, (path, modes, _) in {**FIGURES, **OPTIONAL}.items():
        if trigger not in modes:
            out[name] = NA
            continue
        v = _lookup(summary, path)
        if not _number(v):
            if name in OPTIONAL:
                out[name] = NA
                continue
            got = "absent" if v is None else f"{v!r}, not a number"
            raise MissingFigureError(
                f"{name} ({'.'.join(path)} in summary.json) is {got} in the {trigger} run at"
                f" {rate:g} Hz ({folder}): the {trigger} mode measures it, so the benchmark"
                " cannot go on without it"
            )
        out[name] = v
    out["policy"] = ((summary.get("scheduling") or {}).get("controller") or {}).get("policy")
    return out


def combine(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One value per figure over the repeats: the median or the worst (:data:`FIGURES`)."""
    out: dict[str, Any] = {}
    for name, (_, _, how) in {**FIGURES, **OPTIONAL}.items():
        vals = [r[name] for r in runs if _number(r[name])]
        if not vals:
            out[name] = NA
        elif how == WORST:
            out[name] = max(vals)
        else:
            out[name] = statistics.median(vals)
    out["d_star_us"] = out.pop("d_star_s") * 1e6
    out["policy"] = runs[0]["policy"]
    out["each_repeat"] = runs
    return out


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

    from hil.analysis.measure.stats import summarize_ns
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


def one_rate(rate: float, a: argparse.Namespace, rtt_p50: float, tmp: Path) -> dict[str, Any]:
    """Both trigger modes at ``rate``, ``a.repeats`` times each, beside cyclictest and a paced
    ping-pong at the same rate."""
    from bench.cyclictest_baseline import baseline as cyclictest

    ct = cyclictest(round(1e6 / rate), min(a.duration, 10.0), a.repeats, a.idle == "poll")
    per = {}
    for trigger in ("periodic", "on_state"):
        per[trigger] = combine(
            [
                run_loop(rate, a.duration, trigger, tmp, a.tick_phase, a.idle)
                for _ in range(a.repeats)
            ]
        )
    paced = [paced_pingpong(rate, 2000 if a.quick else 10_000) for _ in range(a.repeats)]
    paced_p50 = statistics.median(x["p50_us"] for x in paced)
    p, o = per["periodic"], per["on_state"]
    med = ct["median"]
    return {
        "periodic": p,
        "on_state": o,
        "cyclictest_p50_us": med["p50_us"],
        "cyclictest_p99_us": med["p99_us"],
        "cyclictest_max_us": max(r["max_us"] for r in ct["runs"]),  # the worst repeat's
        "wakeup_p99_ratio_to_cyclictest": p["wakeup_p99_us"] / max(med["p99_us"], 1),
        "loop_p50_ratio_to_pingpong": o["loop_p50_us"] / rtt_p50,
        "paced_pingpong_rtt_p50_us": paced_p50,
        "loop_p50_ratio_to_paced_pingpong": o["loop_p50_us"] / paced_p50,
        "periodic_adds_to_s2a_p50_us": p["s2a_p50_us"] - o["s2a_p50_us"],
        # the periodic mode's rate only: on_state has no tick to miss (its rate is n/a)
        "miss_rate_ok": p["miss_rate"] < 0.001,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--rates", type=float, nargs="+", default=[500.0, 1000.0, 2000.0])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="5 s runs, 1 repeat")
    phase = "[realtime] tick_phase of the periodic runs (docs/realtime.md)"
    ap.add_argument("--tick-phase", choices=("half", "auto"), default="half", help=phase)
    idle = (
        "[realtime] idle of the runs, and of the baselines: with 'poll' (the default, as the "
        "services run) this process holds the CPUs out of slow idle states for the whole "
        "benchmark, so the ping-pong runs under the loop's machine setting (cyclictest makes "
        "the same request itself)"
    )
    ap.add_argument("--idle", choices=IDLE_POLICIES, default="poll", help=idle)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    if a.idle == "poll":
        from runtime.realtime import hold_cpu_latency

        try:
            hold_cpu_latency()
        except OSError as exc:
            print(f"bench_rt_loop: CPU latency request refused ({exc})", file=sys.stderr)
    if a.quick:
        a.duration, a.repeats = 5.0, 1
    from bench.zenoh_pingpong import zenoh_pingpong

    result: dict[str, Any] = {
        "duration_s": a.duration,
        "repeats": a.repeats,
        "tick_phase": a.tick_phase,
        "idle": a.idle,
        "over_repeats": {
            "median": sorted(n for n, f in {**FIGURES, **OPTIONAL}.items() if f[2] == MEDIAN),
            "worst": sorted(n for n, f in {**FIGURES, **OPTIONAL}.items() if f[2] == WORST),
            "note": "p50 and p99 are medians of the repeats' own p50 and p99 (not percentiles "
            "of the pooled samples); maxima, miss counts and miss rates are the worst repeat's; "
            "each_repeat holds every repeat's figures; n/a: not measured in that trigger mode",
        },
        "rates": {},
    }
    pp = [zenoh_pingpong(n=2000 if a.quick else 10_000) for _ in range(a.repeats)]
    rtt_p50 = statistics.median(p["rtt_p50_us"] for p in pp)
    result["zenoh_pingpong_rtt_p50_us"] = rtt_p50
    try:
        with tempfile.TemporaryDirectory() as tmpd:
            for rate in a.rates:
                result["rates"][f"{rate:g}"] = one_rate(rate, a, rtt_p50, Path(tmpd))
    except MissingFigureError as exc:
        print(f"bench_rt_loop: FAILED: {exc}", file=sys.stderr)
        return 2
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

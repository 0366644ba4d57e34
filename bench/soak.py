"""Soak: a long run at 1 kHz with both paths live (Zenoh applied, CAN as shadow).

    python bench/soak.py [--minutes 10] [--warmup 60] [--out FILE]

Prints, as JSON and a short table: each process's resident memory after warm-up and at the end
(target: growth under 5 MB for each: the plant, the controller, and hil run over its
recording phase, which ends when the services exit; its analysis afterwards is a peak),
wake-up lateness and command-age p99 and max per minute (first against last; from one
hil.analysis.measure of the whole run, a stall counted whole in the minute where it ended:
hil.analysis.measure.windows), messages lost per stream (none unless injected), and the run's
largest stall with its cause. A process whose memory growth could not be measured (too few readings)
fails the target, named on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from longrun import growth_kb, growth_verdict, per_minute, run_sampled


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=60.0, help="seconds before memory counts")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--keep", type=Path, help="keep the run folder here")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="hil-soak-") as tmp:
        run_dir = a.keep or Path(tmp) / "run"
        sampled = run_sampled(run_dir, a.minutes * 60.0, rate=a.rate)
        summary = json.loads((run_dir / "summary.json").read_text())
        minutes = per_minute(run_dir)
    memory = {
        name: {**growth_kb(series, a.warmup), "peak_kb": sampled.peak_kb.get(name)}
        for name, series in sampled.rss.items()
    }
    stalls = (summary.get("certificate") or {}).get("stalls") or []
    result = {
        "minutes": a.minutes,
        "rate_hz": a.rate,
        "memory": memory,
        "recording_end_s": sampled.recording_end_s,
        "per_minute": minutes,
        "first_minute": minutes[0] if minutes else None,
        "last_minute": minutes[-1] if minutes else None,
        "messages_lost": {k: v.get("lost") for k, v in (summary.get("messages") or {}).items()},
        "largest_stall": stalls[0] if stalls else None,
        "certificate": {
            k: (summary.get("certificate") or {}).get(k) for k in ("d_max_s", "d_star_s", "held")
        },
    }
    services = growth_verdict(memory, ("plant", "controller"))
    every = growth_verdict(memory, ("plant", "controller", "hil_run"))
    # A growth that could not be measured fails the target (it is never read as 0).
    result["services_growth_under_5mb"] = services["ok"]
    result["all_growth_under_5mb"] = every["ok"]
    result["growth_unknown"] = every["unknown"]
    text = json.dumps(result, indent=2)
    print(text)
    for name, mem in memory.items():
        if mem["growth_kb"] is None:
            continue  # named below as a failure
        line = f"{name:12} after warm-up {mem['after_warmup_kb']} kB, end {mem['end_kb']} kB, "
        print(line + f"growth {mem['growth_kb']} kB, peak {mem['peak_kb']} kB", file=sys.stderr)
    for name, why in every["unknown"].items():
        print(f"FAIL: memory growth of {name} unknown ({why})", file=sys.stderr)
    if a.out:
        a.out.write_text(text)
    return 0 if result["all_growth_under_5mb"] else 1


if __name__ == "__main__":
    sys.exit(main())

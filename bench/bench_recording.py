"""The cost of the recording's crash safety: chunks closed and flushed every ``flush_interval``.

    python bench/bench_recording.py RUN_DIR [--intervals 0.05 0.1 1 0]

Re-records the messages of a run's ``recording.mcap`` with each flush interval (0: only 1 MiB
chunks, as without crash safety), replaying the messages' own log times as the writer's clock,
and prints the file size and the writing time per message (medians of 3 repeats).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.bench.recorder import RecordingWriter
from hil.folder.recording import read_messages


def rerecord(messages: list, interval: float, out: Path) -> tuple[int, float]:
    w = RecordingWriter(out, flush_interval=interval if interval > 0 else 1e12)
    now = [messages[0].log_time_ns / 1e9 if messages else 0.0]
    w._clock = lambda: now[0]  # the messages' own time: the run's pace, not this loop's
    w._next_flush = now[0] + w._flush_interval
    t0 = time.perf_counter()
    for m in messages:
        now[0] = m.log_time_ns / 1e9
        w.write(m.topic, m.log_time_ns, m.data, publish_time_ns=m.publish_time_ns)
    w.close()
    return out.stat().st_size, (time.perf_counter() - t0) / max(1, len(messages))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--intervals", type=float, nargs="+", default=[0.05, 0.1, 1.0, 0.0])
    a = ap.parse_args(argv)
    messages = list(read_messages(a.run_dir / "recording.mcap"))
    span = (messages[-1].log_time_ns - messages[0].log_time_ns) / 1e9 if messages else 0.0
    result = {"messages": len(messages), "span_s": span, "intervals": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for interval in a.intervals:
            runs = [rerecord(messages, interval, Path(tmp) / f"r{interval}.mcap") for _ in range(3)]
            result["intervals"][f"{interval:g}"] = {
                "bytes": runs[0][0],
                "us_per_message": statistics.median(r[1] for r in runs) * 1e6,
            }
    base = result["intervals"].get("0")
    for v in result["intervals"].values():
        if base:
            v["size_vs_1MiB_chunks"] = v["bytes"] / base["bytes"]
            v["time_vs_1MiB_chunks"] = v["us_per_message"] / base["us_per_message"]
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The live view's effect on the loop: ``hil run`` with and without ``--live``, same scenario.

Each repeat runs the paper's tracking circle (Zenoh command path, CAN live as shadow as by
default, so the view also serves the drive frames) once without the live view and once with it
and a Foxglove WebSocket client (the ``websockets`` package) subscribed to every channel the
whole run: the view's worst case, every message serialized and sent. The order alternates
between repeats, so a machine that slows down over the benchmark does not favour one side.
Figures (bench/bench_rt_loop.py's, from each run's summary.json): loop (transport + compute)
p50/p99, wake-up lateness p50/p99, deadline misses, command age max, the certificate's stall
count; then the change with the view (target: loop p50 within 5 %, no new stalls), and the
view's own cadence: the gaps between its timing snapshots, due once a second (median over the
repeats; tests/test_live.py checks only that they come, in order).

    python bench/bench_live.py                  # 30 s per run, 3 repeats, 1 kHz
    python bench/bench_live.py --quick          # 5 s per run, 1 repeat
Prints one JSON object (also written with --out FILE).
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import _here  # noqa: F401 - this checkout first on sys.path

from bench.bench_rt_loop import combine, figures_of
from hil.verdict import EXIT_CODE  # the codes of a verdict: the command worked
from tests.procs import free_tcp_port

ROOT = Path(__file__).resolve().parent.parent
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def _client(url: str, stop: threading.Event, counts: dict[str, Any]) -> None:
    """Subscribe to every advertised channel (also those advertised later) until ``stop``;
    the log times of the view's timing snapshots go to ``counts["timing_ns"]``."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    with connect(url, subprotocols=SUBPROTOCOLS, open_timeout=30, max_size=None) as ws:
        next_id, timing_ids = 1, set()
        while not stop.is_set():
            try:
                frame = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except ConnectionClosed:
                return
            if isinstance(frame, bytes):
                counts["messages"] = counts.get("messages", 0) + 1
                counts["bytes"] = counts.get("bytes", 0) + len(frame)
                sub, log_ns = struct.unpack_from("<IQ", frame, 1)
                if sub in timing_ids:
                    counts.setdefault("timing_ns", []).append(log_ns)
                continue
            msg = json.loads(frame)
            if msg.get("op") == "advertise":
                subs = [{"id": next_id + i, "channelId": ch["id"]}
                        for i, ch in enumerate(msg["channels"])]  # fmt: skip
                timing_ids |= {next_id + i for i, ch in enumerate(msg["channels"])
                               if ch["topic"].endswith("/live/timing")}  # fmt: skip
                next_id += len(subs)
                ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))


def _cadence(timing_ns: list[int]) -> dict[str, Any]:
    """The gaps between the view's timing snapshots (due once a second; the view runs at nice
    10, below the run's services): median and extremes, s."""
    gaps = [(b - a) / 1e9 for a, b in itertools.pairwise(timing_ns)]
    if not gaps:
        return {"count": 0}
    return {"count": len(gaps), "p50_s": statistics.median(gaps), "min_s": min(gaps),
            "max_s": max(gaps)}  # fmt: skip


def _url(out: Path, proc: subprocess.Popen, timeout: float = 120.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        log = out / "live.log"
        for line in log.read_text().splitlines() if log.exists() else []:
            if line.startswith("live: ws://"):
                return line.split(" ", 1)[1]
        if proc.poll() is not None:
            raise RuntimeError(f"hil run ended before its live view listened ({out})")
        time.sleep(0.05)
    raise RuntimeError("the live view never listened")


def run_once(rate: float, duration: float, live: bool, out: Path) -> dict[str, Any]:
    argv = [sys.executable, "-m", "hil", "run", "--rate", str(rate), "--duration", str(duration),
            "--cmd-path", "zenoh", "--quiet", "--no-report", "--out", str(out)]  # fmt: skip
    if live:
        argv += ["--live", str(free_tcp_port())]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    stop, counts = threading.Event(), {"messages": 0, "bytes": 0}
    watcher = None
    try:
        if live:
            watcher = threading.Thread(target=_client, args=(_url(out, proc), stop, counts))
            watcher.start()
        _, err = proc.communicate(timeout=duration + 240)
    finally:
        stop.set()
        if watcher is not None:
            watcher.join(timeout=30)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    if proc.returncode not in EXIT_CODE.values():
        raise RuntimeError(err.decode(errors="replace")[-2000:])
    summary = json.loads((out / "summary.json").read_text())
    figs = figures_of(summary, rate, "periodic", out)
    figs["stalls"] = len((summary.get("certificate") or {}).get("stalls") or [])
    figs["cadence"] = _cadence(counts.pop("timing_ns", [])) if live else None
    figs["client"] = counts if live else None
    return figs


def _change(off: dict[str, Any], on: dict[str, Any]) -> dict[str, Any]:
    def rel(name: str) -> float | None:
        a, b = off.get(name), on.get(name)
        ok = isinstance(a, int | float) and isinstance(b, int | float) and a
        return (b - a) / a if ok else None

    return {
        "loop_p50_rel": rel("loop_p50_us"),
        "wakeup_p50_rel": rel("wakeup_p50_us"),
        "s2a_p50_rel": rel("s2a_p50_us"),
        "new_stalls": max(on["stalls"]) - max(off["stalls"]),
        "deadline_misses": {"off": off["deadline_misses"], "live": on["deadline_misses"]},
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--rate", type=float, default=1000.0)
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--quick", action="store_true", help="5 s per run, 1 repeat")
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    if a.quick:
        a.duration, a.repeats = 5.0, 1
    runs: dict[str, list[dict[str, Any]]] = {"off": [], "live": []}
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        for i in range(a.repeats):
            order = ("off", "live") if i % 2 == 0 else ("live", "off")
            for mode in order:
                out = Path(tmp) / f"{mode}-{i}"
                runs[mode].append(run_once(a.rate, a.duration, mode == "live", out))
    result: dict[str, Any] = {"rate_hz": a.rate, "duration_s": a.duration, "repeats": a.repeats}
    for mode, rs in runs.items():
        combined = combine(rs)
        combined["stalls"] = [r["stalls"] for r in rs]
        result[mode] = combined
    # The view's snapshot cadence: the median over the repeats of each run's median gap (a
    # loaded host delays the nice-10 view; its schedule then catches up).
    cadences = [r["cadence"] for r in runs["live"] if (r["cadence"] or {}).get("count")]
    result["live"]["timing_cadence"] = {
        "p50_s": statistics.median(c["p50_s"] for c in cadences) if cadences else None,
        "min_s": min((c["min_s"] for c in cadences), default=None),
        "max_s": max((c["max_s"] for c in cadences), default=None),
        "runs": cadences,
    }
    result["change_with_live"] = _change(result["off"], result["live"])
    text = json.dumps(result, indent=2, default=str)
    print(text)
    if a.out:
        a.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

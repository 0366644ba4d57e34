"""Shared by the long-run benchmarks (bench/soak.py, bench/bench_long_run.py): one ``hil run``
with the services' resident memory sampled every second, and per-minute figures from its logs.

Resident memory is read from ``/proc/PID/status`` (VmRSS) of each process by the PIDs
``hil run`` writes to ``processes.json``; ``/usr/bin/time``-style peaks come from VmHWM.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def rss_kb(pid: int, field_name: str = "VmRSS") -> int | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field_name + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _alive(pid: int) -> bool:
    """Running, not a zombie (a child of hil run that exited stays a zombie until reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@dataclass
class Sampled:
    """RSS (kB) of each process, sampled once a second: (t_s since the epoch, kB)."""

    rss: dict[str, list[tuple[float, int]]] = field(default_factory=dict)
    peak_kb: dict[str, int] = field(default_factory=dict)
    # hil run's own series stops when the services have exited: what follows is the run's
    # analysis (summary.json), whose memory is a peak, not growth; ``peak_kb`` still sees it.
    recording_end_s: float | None = None


def run_sampled(out: Path, duration_s: float, *args: str, rate: float = 1000.0) -> Sampled:
    """``hil run`` of the paper's circle (both paths live) for ``duration_s`` at ``rate``,
    sampling the plant's, the controller's and hil run's own memory every second."""
    argv = [sys.executable, "-m", "hil", "run", "--rate", str(rate), "--duration", str(duration_s),
            "--quiet", "--no-report", "--out", str(out), *args]  # fmt: skip
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    got = Sampled()
    pids: dict[str, int] = {}
    t0 = None
    next_rss = 0.0
    try:
        while proc.poll() is None:
            if not pids and (out / "processes.json").is_file():
                pids = {**json.loads((out / "processes.json").read_text()), "hil_run": proc.pid}
                t0 = time.monotonic()
            sample_rss = time.monotonic() >= next_rss
            if sample_rss:
                next_rss = time.monotonic() + 1.0
            services = [pid for name, pid in pids.items() if name != "hil_run"]
            if pids and got.recording_end_s is None and not any(_alive(p) for p in services):
                got.recording_end_s = time.monotonic() - (t0 or 0.0)
            for name, pid in pids.items():
                recording = got.recording_end_s is None or name != "hil_run"
                kb = rss_kb(pid) if sample_rss and recording else None
                if kb is not None:
                    got.rss.setdefault(name, []).append((time.monotonic() - (t0 or 0.0), kb))
                # the high-water mark 4 times a second: hil run's end-of-run peak is brief
                hwm = rss_kb(pid, "VmHWM")
                if hwm is not None:
                    got.peak_kb[name] = max(got.peak_kb.get(name, 0), hwm)
            time.sleep(0.25)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    if proc.returncode not in (0, 1):
        raise RuntimeError(proc.stderr.read().decode(errors="replace")[-3000:])
    return got


def growth_kb(series: list[tuple[float, int]], warmup_s: float) -> dict[str, Any]:
    """RSS after warm-up (median of the first minute after it) and at the end (median of the
    last 10 samples), and the growth between them."""
    after = [kb for t, kb in series if t >= warmup_s]
    if len(after) < 20:
        return {"after_warmup_kb": None, "end_kb": None, "growth_kb": None}
    start = float(np.median(after[: min(60, len(after) // 2)]))
    end = float(np.median(after[-10:]))
    return {"after_warmup_kb": start, "end_kb": end, "growth_kb": end - start}


def per_minute(run_dir: Path) -> list[dict[str, Any]]:
    """Wake-up lateness p99 and applied-path command-age p99 per minute of the run (µs)."""
    from hil.measure import load_folder_logs, measure
    from hil.measure.age import AgeSegments, age_summary

    logs = load_folder_logs(run_dir)
    if logs is None:
        return []
    m = measure(logs)
    epoch = logs.epoch_ns
    t, late = m.series.get("wakeup_lateness", (np.zeros(0), np.zeros(0)))
    seg: AgeSegments = m.series[f"command_age_{m.series.get('applied_path', 'zenoh')}"]
    h = int(logs.pmeta.get("plant_step_ns") or 100_000)
    out = []
    minutes = int(np.ceil((m.window_ns[1] - m.window_ns[0]) / 60e9))
    for k in range(minutes):
        lo, hi = epoch + int(k * 60e9), epoch + int((k + 1) * 60e9)
        sel = (t >= k * 60) & (t < (k + 1) * 60)
        keep = (seg.start >= lo) & (seg.start < hi)
        part = AgeSegments(seg.start[keep], np.minimum(seg.end[keep], hi), seg.sample[keep])
        age = age_summary(part, lo, h)
        out.append(
            {
                "minute": k + 1,
                "wakeup_lateness_p99_us": float(np.percentile(late[sel], 99, method="inverted_cdf"))
                / 1e3
                if sel.any()
                else None,
                "command_age_p99_us": age["p99_us"],
                "command_age_max_us": age["max_us"],
            }
        )
    return out

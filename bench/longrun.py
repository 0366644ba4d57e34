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

from hil.verdict import EXIT_CODE  # noqa: E402 (a verdict's codes: the command worked)


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
    if proc.returncode not in EXIT_CODE.values():
        raise RuntimeError(proc.stderr.read().decode(errors="replace")[-3000:])
    return got


GROWTH_LIMIT_KB = 5 * 1024
MIN_READINGS = 20


def growth_kb(series: list[tuple[float, int]], warmup_s: float) -> dict[str, Any]:
    """RSS after warm-up (median of the first minute after it) and at the end (median of the
    last 10 samples), and the growth between them. Too few readings after the warm-up give
    ``growth_kb`` None with the reason in ``unknown``: never a growth of 0."""
    after = [kb for t, kb in series if t >= warmup_s]
    if len(after) < MIN_READINGS:
        return {
            "after_warmup_kb": None,
            "end_kb": None,
            "growth_kb": None,
            "unknown": f"{len(after)} memory readings after the {warmup_s:g} s warm-up "
            f"({MIN_READINGS} needed)",
        }
    start = float(np.median(after[: min(60, len(after) // 2)]))
    end = float(np.median(after[-10:]))
    return {"after_warmup_kb": start, "end_kb": end, "growth_kb": end - start}


def growth_verdict(memory: dict[str, dict[str, Any]], names: tuple[str, ...]) -> dict[str, Any]:
    """Whether every process in ``names`` grew less than 5 MB; a process whose growth is
    unknown (no memory entry, too few readings) fails the target and is named."""
    unknown = {
        n: (memory.get(n) or {}).get("unknown") or "no memory readings at all"
        for n in names
        if (memory.get(n) or {}).get("growth_kb") is None
    }
    over = [n for n in names if n not in unknown and memory[n]["growth_kb"] >= GROWTH_LIMIT_KB]
    return {"ok": not unknown and not over, "over_5mb": over, "unknown": unknown}


def per_minute(run_dir: Path) -> list[dict[str, Any]]:
    """Wake-up lateness and applied-path command age, p99 and max (µs), per minute of the run,
    from one :func:`hil.analysis.measure.measure` of the whole run
    (:func:`hil.analysis.measure.windows.per_window`:
    a stall across a minute's edge counts whole in the minute where it ended, never clipped)."""
    from hil.analysis.measure import load_folder_logs, measure
    from hil.analysis.measure.windows import MINUTE_NS, per_window

    logs = load_folder_logs(run_dir)
    if logs is None:
        return []
    m = measure(logs)
    # the plant's step, with hil.analysis.measure's own fallback (a tenth of the control period)
    step = int(
        logs.pmeta.get("plant_step_ns")
        or max(1, int(logs.pmeta.get("control_period_ns") or 1_000_000) // 10)
    )
    rows = per_window(m.series, logs.epoch_ns, m.window_ns, step, MINUTE_NS)
    return [{"minute": r.pop("window") + 1, **r} for r in rows]

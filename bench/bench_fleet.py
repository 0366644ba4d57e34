"""A fleet of N robots on this machine: where it stops meeting its deadlines, and why.

For each rate and each N, ``hil fleet paper_tracking --robots N --per-process K`` over loopback
(K = N by default: one plant process emulating every robot, one controller process hosting
every robot's controller, one recorder, each robot on its own keys and deadlines; ``--per-process
1``: each robot its own ``hil run``, plant and controller processes and recorder). Per
(rate, N): the fleet's command-age p99 (max over robots) beside D*, the samples without a
command, the controller deadline-miss rate, how many robots passed, and the machine's CPU use
over the fleet's run (from /proc/stat: user + system of both cores, the why). Writes
``fleet_scaling.json`` and a plot ``fleet_scaling.png`` (each figure against N).

    python bench/bench_fleet.py                      # 100 Hz: N = 1, 4, 16, 64; 500 Hz: 1, 4, 16
    python bench/bench_fleet.py --n 1 4 --rates 100  # a subset
    python bench/bench_fleet.py --per-process 1      # one hil run per robot (3 N processes)
    python bench/bench_fleet.py --duration 10 --out DIR
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import _here  # noqa: F401  (this checkout first on sys.path)

ROOT = Path(__file__).resolve().parents[1]


def cpu_ticks() -> tuple[int, int]:
    """(busy, total) jiffies of all cores since boot."""
    f = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = f[3] + f[4]
    return sum(f) - idle, sum(f)


DEFAULT_N = {100.0: [1, 4, 16, 64], 500.0: [1, 4, 16]}


def one(n: int, rate: float, duration: float, out: Path, per: int = 0) -> dict[str, Any]:
    b0, t0 = cpu_ticks()
    w0 = time.monotonic()
    k = min(per or n, n)
    args = ["--robots", str(n), "--rate", str(rate), "--duration", str(duration)]
    args += ["--per-process", str(k)]
    done = subprocess.run(
        [sys.executable, "-m", "hil", "fleet", "paper_tracking", *args, "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    b1, t1 = cpu_ticks()
    try:
        fleet = json.loads((out / "fleet.json").read_text())
    except (OSError, ValueError):
        return {"error": done.stderr[-2000:]}
    f = fleet["fleet"]
    d_star = [r["d_star_s"] for r in fleet["per_robot"] if r.get("d_star_s")]
    return {
        "robots": n,
        "rate_hz": rate,
        "per_process": k,
        "processes": 3 * -(-n // k),
        "passed": f["passed"],
        "command_age_p99_ms_max": (f["command_age_p99_us_max"] or 0) / 1e3,
        "d_star_ms": min(d_star) * 1e3 if d_star else None,
        "samples_without_command_rate": f["samples_without_command_rate"],
        "deadline_miss_rate": f["deadline_miss_rate"],
        "cpu_busy": (b1 - b0) / max(1, t1 - t0),
        "wall_s": time.monotonic() - w0,
        **why(out, n),
    }


def why(out: Path, n: int) -> dict[str, Any]:
    """Where the time went, worst robot: the processes' CPU (robot1's, shared by its group),
    the wake-ups (scheduling) and the hops (transport) of every robot."""
    host: dict[str, Any] = {}
    worst: dict[str, float] = {}
    for i in range(1, n + 1):
        try:
            s = json.loads((out / f"robot{i}" / "summary.json").read_text())
        except (OSError, ValueError):
            continue
        if i == 1:
            host = s.get("host") or {}
        t = s.get("timing") or {}
        for key in ("wakeup_lateness", "plant_wakeup_lateness", "hop_state", "hop_cmd_zenoh"):
            p99 = (t.get(key) or {}).get("p99_us")
            if p99 is not None:
                worst[f"{key}_p99_ms_max"] = max(worst.get(f"{key}_p99_ms_max", 0.0), p99 / 1e3)
    cpu = {f"{k}": host.get(k) for k in ("plant_cpu_pct", "controller_cpu_pct", "recorder_cpu_pct")}
    return {**cpu, **worst}


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ("command_age_p99_ms_max", "samples_without_command_rate", "deadline_miss_rate")
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.2))
    for rate in sorted({r["rate_hz"] for r in rows}):
        mine = [r for r in rows if r["rate_hz"] == rate and "error" not in r]
        ns = [r["robots"] for r in mine]
        for ax, key in zip(axes, (*keys, "cpu_busy"), strict=True):
            ax.plot(ns, [r[key] or 0 for r in mine], "o-", label=f"{rate:g} Hz")
            ax.set_title(key, fontsize=9)
            ax.set_xscale("log", base=2)
            ax.set_xlabel("robots N")
        if mine and mine[0]["d_star_ms"]:
            axes[0].axhline(mine[0]["d_star_ms"], color="r", lw=0.8, ls="--")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="+", default=None)
    ap.add_argument("--rates", type=float, nargs="+", default=[100.0, 500.0])
    ap.add_argument("--duration", type=float, default=5.0)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--per-process", type=int, default=0, help="robots per process (0: all)")
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    rows = []
    for rate in a.rates:
        for n in a.n or DEFAULT_N.get(rate, [1, 4, 16]):
            row = one(n, rate, a.duration, out / f"r{rate:g}-n{n}", a.per_process)
            row.setdefault("robots", n)
            row.setdefault("rate_hz", rate)
            rows.append(row)
            print(json.dumps(row), flush=True)
    (out / "fleet_scaling.json").write_text(json.dumps(rows, indent=2) + "\n")
    plot(rows, out / "fleet_scaling.png")
    print(f"written: {out}/fleet_scaling.json, fleet_scaling.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

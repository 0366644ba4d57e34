"""Long runs: how memory and the report's time scale with the run's length.

    python bench/bench_long_run.py                  # 1, 2 and 10 minutes
    python bench/bench_long_run.py --full           # also 60 minutes
    python bench/bench_long_run.py --lengths 1 2 --out result.json
    python bench/bench_long_run.py --full --keep DIR   # keep the run folders, then later:
    python bench/bench_long_run.py --report-only DIR   # report again on them (quiet machine)

Each length is one ``hil run`` of the paper's circle at 1 kHz with both paths live (Zenoh
applied, CAN as shadow), its processes' resident memory sampled by PID
(:func:`longrun.run_sampled`), then ``hil report DIR`` (with the ideal trajectory, as a user
runs it) in a subprocess whose peak resident memory comes from the kernel (``wait4``'s
``ru_maxrss``). Printed per length, and as JSON with ``--out``:

- each process's (plant, controller, hil run) peak resident memory, and for the services their
  memory after warm-up and at the end and the growth between them (target: under 5 MB; a
  growth that could not be measured, too few readings, is "unknown" and fails the target);
- the report's wall time and peak memory, and its time per minute of run (flat = linear);
- the files' sizes: the hop logs, the recording, trace.csv.

Targets: the report of a 60-minute run in under 2 minutes and 1.5 GB on a 2-core
machine; service memory flat.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from longrun import ROOT, growth_kb, growth_verdict, run_sampled

from hil.verdict import EXIT_CODE  # the codes of a verdict: the command worked

FILES = ("controller.hoplog", "plant.hoplog", "recording.mcap", "trace.csv")
RUN_RECORD = "bench_run.json"


def report_sampled(run_dir: Path, *args: str) -> dict[str, Any]:
    """``hil report RUN_DIR`` in a subprocess: wall time, exit code and peak RSS (kB)."""
    argv = [sys.executable, "-m", "hil", "report", str(run_dir), *args]
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    assert proc.stderr is not None
    err = proc.stderr.read()  # small: the report prints little; read until it exits
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.monotonic() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode not in EXIT_CODE.values():
        raise RuntimeError(err.decode(errors="replace")[-3000:])
    return {
        "wall_s": round(seconds, 2),
        "peak_rss_kb": int(usage.ru_maxrss),
        "exit_code": proc.returncode,
        "user_s": round(usage.ru_utime, 2),
        "sys_s": round(usage.ru_stime, 2),
    }


def run_length(minutes: float, root: Path, warmup: float, rate: float) -> Path:
    """One run of ``minutes``; its run-phase figures are kept in the folder (``bench_run.json``)
    so ``--report-only`` can report again on it later (a quiet machine, newer code)."""
    run_dir = root / f"run-{minutes:g}min"
    t0 = time.monotonic()
    sampled = run_sampled(run_dir, minutes * 60.0, rate=rate)
    run_wall = time.monotonic() - t0
    memory = {}
    for name, series in sampled.rss.items():
        # hil run's growth: over its recording phase (its series stops when the services exit)
        memory[name] = {"peak_kb": sampled.peak_kb.get(name), **growth_kb(series, warmup)}
    sizes = {
        name: (run_dir / name).stat().st_size if (run_dir / name).is_file() else None
        for name in FILES
    }
    summary = json.loads((run_dir / "summary.json").read_text())
    record = {
        "minutes": minutes,
        "rate_hz": rate,
        "samples": summary.get("samples"),
        "run_wall_s": round(run_wall, 1),
        "memory": memory,
        "files_bytes": sizes,
    }
    # A growth that could not be measured fails the target (it is never read as 0).
    verdict = growth_verdict(memory, ("plant", "controller"))
    record["services_growth_under_5mb"] = verdict["ok"]
    record["growth_unknown"] = verdict["unknown"]
    (run_dir / RUN_RECORD).write_text(json.dumps(record, indent=2))
    return run_dir


def report_length(run_dir: Path) -> dict[str, Any]:
    """``hil report`` on a kept run folder, with the run-phase figures it recorded."""
    record = json.loads((run_dir / RUN_RECORD).read_text())
    report = report_sampled(run_dir)
    return {
        **record,
        "report": {**report, "s_per_run_minute": round(report["wall_s"] / record["minutes"], 2)},
    }


def _mb(kb: Any) -> str:
    return "-" if kb is None else f"{kb / 1024:.0f}"


def table(rows: list[dict[str, Any]]) -> str:
    head = (
        "| minutes | plant peak / growth MB | controller peak / growth MB | hil run peak MB "
        "| report s (s per run min) | report peak MB | hop logs MB | recording MB | trace MB |"
    )
    lines = [head, "|" + "---|" * 9]
    for r in rows:
        m, rep, f = r["memory"], r["report"], r["files_bytes"]

        def svc(name: str, m: dict[str, Any] = m) -> str:
            d = m.get(name, {})
            growth = d.get("growth_kb")
            return f"{_mb(d.get('peak_kb'))} / " + (
                "unknown" if growth is None else f"{growth / 1024:.2f}"
            )

        logs = sum(f[k] or 0 for k in ("controller.hoplog", "plant.hoplog"))
        lines.append(
            f"| {r['minutes']:g} | {svc('plant')} | {svc('controller')} | "
            f"{_mb(m.get('hil_run', {}).get('peak_kb'))} | {rep['wall_s']:.1f} "
            f"({rep['s_per_run_minute']:.2f}) | {_mb(rep['peak_rss_kb'])} | {logs / 2**20:.0f} | "
            f"{(f['recording.mcap'] or 0) / 2**20:.0f} | {(f['trace.csv'] or 0) / 2**20:.0f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--lengths", type=float, nargs="+", help="run lengths in minutes")
    ap.add_argument("--full", action="store_true", help="also 60 minutes")
    ap.add_argument("--warmup", type=float, default=10.0, help="seconds before memory counts")
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--out", type=Path, help="write the results as JSON")
    ap.add_argument("--keep", type=Path, help="keep the run folders under this folder")
    ap.add_argument(
        "--report-only",
        type=Path,
        metavar="ROOT",
        help="no new runs: report again on the run-*min folders kept under ROOT by --keep",
    )
    a = ap.parse_args(argv)
    lengths = a.lengths or [1.0, 2.0, 10.0]
    if a.full and 60.0 not in lengths:
        lengths.append(60.0)
    rows = []
    if a.report_only is not None:
        folders = sorted(
            (d for d in a.report_only.glob("run-*min") if (d / RUN_RECORD).is_file()),
            key=lambda d: float(d.name[4:-3]),
        )
        if not folders:
            ap.error(f"no run-*min folder with {RUN_RECORD} under {a.report_only}")
        lengths = [json.loads((d / RUN_RECORD).read_text())["minutes"] for d in folders]
        for d in folders:
            print(f"reporting on {d} ...", file=sys.stderr)
            rows.append(report_length(d))
            print(table(rows[-1:]).splitlines()[-1], file=sys.stderr)
    else:
        with tempfile.TemporaryDirectory(prefix="hil-longrun-") as tmp:
            root = a.keep or Path(tmp)
            root.mkdir(parents=True, exist_ok=True)
            for minutes in lengths:
                print(f"running {minutes:g} min at {a.rate:g} Hz ...", file=sys.stderr)
                rows.append(report_length(run_length(minutes, root, a.warmup, a.rate)))
                print(table(rows[-1:]).splitlines()[-1], file=sys.stderr)
    result = {
        "lengths_min": lengths,
        "rows": rows,
        "services_flat": all(r["services_growth_under_5mb"] for r in rows),
        "report_targets": {"max_s_at_60min": 120, "max_peak_mb": 1536},
    }
    text = json.dumps(result, indent=2)
    print(text)
    print(table(rows))
    for r in rows:
        for name, why in (r.get("growth_unknown") or {}).items():
            print(f"FAIL: {r['minutes']:g} min: memory growth of {name} unknown ({why})",
                  file=sys.stderr)  # fmt: skip
    if a.out:
        a.out.write_text(text)
    return 0 if result["services_flat"] else 1


if __name__ == "__main__":
    sys.exit(main())

"""Every figure of docs/performance.md's table in one command, each beside the baseline that the
same run measured, and whether its target is met.

It runs the figures' own benchmarks one after the other, each in its own process (so one's
threads and compiled kernels never share a core with the next one's), reads their JSON and
prints one table (also written as JSON with ``--out``):

- ``bench_rt_loop.py --tick-phase auto``: wake-up lateness against cyclictest at 500 Hz, 1 kHz
  and 2 kHz; the loop's transport + compute p50 against a paced raw Zenoh ping-pong; samples
  without command and late commands at 2 kHz (periodic, its tick phase learnt); the highest
  on_state rate with both under 0.1 % (up to 5 kHz);
- ``bench_controller_step.py``: the law's float update against the same equations in one plain
  function;
- ``bench_sweep.py``: the batch path's robot-steps/s against the single-run path;
- ``bench_long_run.py --report-only DIR`` with ``--long-run DIR``: ``hil report`` of the run
  folders kept by ``bench_long_run.py --full --keep DIR`` (an hour's run takes an hour, so it is
  made once and reported on again with newer code).

Medians over repeats for medians, the worst repeat for maxima (each benchmark's own rule).

    python bench/bench_performance.py                     # about 25 minutes on 2 cores
    python bench/bench_performance.py --quick             # short runs, one repeat: a smoke test
    python bench/bench_performance.py --long-run DIR      # and the long runs' reports
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
RT_RATES = ("500", "1000", "2000", "5000")
SERVED = 0.001  # samples without command and late commands: below 0.1 % each


@dataclass(frozen=True)
class Row:
    figure: str
    baseline: str
    now: str
    target: str
    met: bool | None  # None: not measured in this run


def _run(argv: list[str], out: Path | None) -> dict[str, Any]:
    """One benchmark in its own process; its JSON from ``out`` or from its last stdout line
    that is a JSON object."""
    print("running", " ".join(argv[1:]), "...", file=sys.stderr, flush=True)
    proc = subprocess.run(argv, stdout=subprocess.PIPE, text=True, cwd=BENCH.parent)
    if out is not None and out.is_file():
        return json.loads(out.read_text())
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise RuntimeError(f"{argv[1]} printed no figures (exit {proc.returncode})")


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.2f} %"


def rt_rows(rt: dict[str, Any]) -> list[Row]:
    """The loop's rows (bench_rt_loop.py's JSON)."""
    rates = rt["rates"]
    rows = []
    for r in ("500", "1000", "2000"):
        if r not in rates:
            continue
        x, p = rates[r], rates[r]["periodic"]
        ratio = x["wakeup_p99_ratio_to_cyclictest"]
        max_ratio = p["wakeup_max_us"] / max(x["cyclictest_max_us"], 1)
        rows.append(Row(
            f"wake-up lateness p99 / max, {r} Hz",
            f"cyclictest p99 {x['cyclictest_p99_us']:.1f} us, max {x['cyclictest_max_us']:.0f} us",
            f"{p['wakeup_p99_us']:.1f} us ({ratio:.2f}x), max {p['wakeup_max_us']:.0f} us "
            f"({max_ratio:.2f}x)",
            "p99 <= 1.2x, max <= 2x", ratio <= 1.2 and max_ratio <= 2.0,
        ))  # fmt: skip
        o = x["on_state"]
        paced = x["loop_p50_ratio_to_paced_pingpong"]
        rows.append(Row(
            f"loop transport + compute p50, {r} Hz (on_state)",
            f"paced Zenoh ping-pong {x['paced_pingpong_rtt_p50_us']:.0f} us",
            f"{o['loop_p50_us']:.0f} us ({paced:.2f}x)", "<= 1.2x paced", paced <= 1.2,
        ))  # fmt: skip
    if "2000" in rates:
        p = rates["2000"]["periodic"]
        without, late = p["samples_without_command_rate"], p["late_commands_rate"]
        rows.append(Row(
            "2 kHz periodic: samples without command / late commands", "-",
            f"{_pct(without)} / {_pct(late)}", "< 0.1 % each",
            without is not None and late is not None and without < SERVED and late < SERVED,
        ))  # fmt: skip
    served = [
        float(r) for r, x in rates.items()
        if (x["on_state"]["samples_without_command_rate"] or 0.0) < SERVED
        and (x["on_state"]["late_commands_rate"] or 0.0) < SERVED
    ]  # fmt: skip
    best = max(served, default=None)
    rows.append(Row(
        "highest on_state rate with < 0.1 % samples without command and late commands",
        "ros2_control 1-2 kHz typical", "none" if best is None else f"{best:g} Hz", "5 kHz",
        best is not None and best >= 5000,
    ))  # fmt: skip
    return rows


def law_rows(law: dict[str, Any]) -> list[Row]:
    """The law's row (bench_controller_step.py's JSON)."""
    return [Row(
        "unified law, one float update (CPU time)",
        f"plain function {law['loop_plain_cpu_us']:.2f} us",
        f"{law['loop_law_cpu_us']:.2f} us ({law['ratio_to_plain']:.3f}x)", "<= 1.2x",
        bool(law["ratio_met"]),
    )]  # fmt: skip


def sweep_rows(sw: dict[str, Any]) -> list[Row]:
    """The batch path's row (bench_sweep.py's JSON)."""
    rate, ratio = sw["batch_robot_steps_per_s"], sw["ratio_batch_to_single"]
    return [Row(
        "batch sweep, robot-steps/s",
        f"single-run path {sw['single_robot_steps_per_s'] / 1e3:.0f} k/s; numpy batch "
        f"{sw['numpy_batch_robot_steps_per_s'] / 1e6:.2f} M/s",
        f"{rate / 1e6:.2f} M/s ({ratio:.0f}x single)", ">= 10 M/s, >= 300x single",
        rate >= 1e7 and ratio >= 300,
    )]  # fmt: skip


def report_rows(lr: dict[str, Any]) -> list[Row]:
    """The long runs' report rows (bench_long_run.py's JSON)."""
    rows = []
    for r in lr["rows"]:
        rep = r["report"]
        mb = rep["peak_rss_kb"] / 1024
        hour = r["minutes"] >= 60
        rows.append(Row(
            f"hil report of a {r['minutes']:g}-minute run", "-",
            f"{rep['wall_s']:.1f} s, peak {mb:.0f} MB",
            "< 45 s, < 1 GB" if hour else "-",
            (rep["wall_s"] < 45 and mb < 1024) if hour else None,
        ))  # fmt: skip
    return rows


def table(rows: list[Row]) -> str:
    met = {True: "met", False: "NOT met", None: "-"}
    out = ["| figure | baseline in the same run | now | target | |", "|---|---|---|---|---|"]
    out += [f"| {r.figure} | {r.baseline} | {r.now} | {r.target} | {met[r.met]} |" for r in rows]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="each benchmark's --quick")
    keep = "report on the run folders kept by bench_long_run.py --keep DIR"
    ap.add_argument("--long-run", type=Path, metavar="DIR", help=keep)
    ap.add_argument("--out", type=Path, help="also write the figures and the table as JSON")
    a = ap.parse_args(argv)
    quick = ["--quick"] if a.quick else []
    py = sys.executable
    rows: list[Row] = []
    raw: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="hil-perf-") as tmp:
        t = Path(tmp)
        steps: list[tuple[str, list[str], Path | None, Callable[[dict[str, Any]], list[Row]]]] = [
            ("rt_loop", [py, str(BENCH / "bench_rt_loop.py"), "--rates", *RT_RATES, *quick,
                         "--tick-phase", "auto", "--out", str(t / "rt.json")], t / "rt.json",
             rt_rows),
            ("law", [py, str(BENCH / "bench_controller_step.py"), *quick], None, law_rows),
            ("sweep", [py, str(BENCH / "bench_sweep.py"), *quick, "--json", str(t / "sw.json")],
             t / "sw.json", sweep_rows),
        ]  # fmt: skip
        if a.long_run is not None:
            lr = t / "lr.json"
            argv_lr = [py, str(BENCH / "bench_long_run.py"), "--report-only", str(a.long_run)]
            steps.append(("long_run", [*argv_lr, "--out", str(lr)], lr, report_rows))
        for name, cmd, out, rows_of in steps:
            raw[name] = _run(cmd, out)
            rows += rows_of(raw[name])
    text = table(rows)
    print(text)
    if a.out:
        a.out.write_text(json.dumps({"figures": raw, "table": text}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

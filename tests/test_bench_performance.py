"""bench/bench_performance.py's table: each row reads the figure its benchmark writes and judges
it against the row's target (the benchmarks themselves run on a quiet machine, not here)."""

from __future__ import annotations

import re
from pathlib import Path

from bench import bench_performance as perf
from bench.bench_rt_loop import FIGURES

BENCH = Path(perf.__file__).resolve().parent


def _mode(without: float, late: float, loop: float) -> dict[str, float]:
    return {"wakeup_p99_us": 30.0, "wakeup_max_us": 90.0, "loop_p50_us": loop,
            "samples_without_command_rate": without, "late_commands_rate": late}  # fmt: skip


def _rate(without: float, late: float) -> dict[str, object]:
    return {
        "periodic": _mode(without, late, 250.0),
        "on_state": _mode(0.0, 0.0, 200.0),
        "cyclictest_p99_us": 29.0, "cyclictest_max_us": 60.0,
        "wakeup_p99_ratio_to_cyclictest": 30.0 / 29.0,
        "paced_pingpong_rtt_p50_us": 180.0, "loop_p50_ratio_to_paced_pingpong": 200.0 / 180.0,
    }  # fmt: skip


def test_the_loop_rows_judge_each_figure_against_its_target():
    rates = {"500": _rate(0.0, 0.0), "1000": _rate(0.0, 0.0), "2000": _rate(0.0005, 0.002)}
    rates["5000"] = _rate(0.0, 0.0)
    rates["5000"]["on_state"] = _mode(0.01, 0.0, 150.0)  # 1 % unserved at 5 kHz
    rows = {r.figure: r for r in perf.rt_rows({"rates": rates})}
    assert rows["wake-up lateness p99 / max, 2000 Hz"].met is True  # 1.03x, max 1.5x
    assert rows["loop transport + compute p50, 1000 Hz (on_state)"].met is True  # 1.11x
    served = rows["2 kHz periodic: samples without command / late commands"]
    assert served.met is False and served.now == "0.05 % / 0.20 %"
    best = rows["highest on_state rate with < 0.1 % samples without command and late commands"]
    assert best.now == "2000 Hz" and best.met is False
    rates["5000"]["on_state"] = _mode(0.0, 0.0, 150.0)
    best = perf.rt_rows({"rates": rates})[-1]
    assert best.now == "5000 Hz" and best.met is True


def test_the_rows_read_keys_their_benchmarks_write():
    """Every per-mode key the loop rows read is a figure of bench_rt_loop.py; every key the
    law, sweep and report rows read is written by its benchmark's source."""
    for key in ("wakeup_p99_us", "wakeup_max_us", "loop_p50_us", "samples_without_command_rate",
                "late_commands_rate"):  # fmt: skip
        assert key in FIGURES, key
    source = perf.Path(perf.__file__).read_text()
    for fn, bench in (("law_rows", "bench_controller_step.py"), ("sweep_rows", "bench_sweep.py"),
                      ("report_rows", "bench_long_run.py")):  # fmt: skip
        body = source.split(f"def {fn}(")[1].split("\ndef ")[0]
        keys = set(re.findall(r"""\[["'](\w+)["']\]""", body)) - {"rows", "report", "minutes"}
        written = (BENCH / bench).read_text()
        assert keys and all(f'"{k}"' in written for k in keys), (bench, keys)


def test_the_sweep_and_report_rows_judge_their_targets():
    sw = {"batch_robot_steps_per_s": 11e6, "ratio_batch_to_single": 160.0,
          "single_robot_steps_per_s": 68e3, "numpy_batch_robot_steps_per_s": 7e6}  # fmt: skip
    (row,) = perf.sweep_rows(sw)
    assert row.met is False and "11.00 M/s (160x single)" in row.now  # 300x not reached
    hour = {"minutes": 60.0, "report": {"wall_s": 40.0, "peak_rss_kb": 900 * 1024}}
    minute = {"minutes": 1.0, "report": {"wall_s": 3.0, "peak_rss_kb": 200 * 1024}}
    rows = perf.report_rows({"rows": [minute, hour]})
    assert [r.met for r in rows] == [None, True]
    hour["report"]["wall_s"] = 50.0
    assert perf.report_rows({"rows": [hour]})[0].met is False

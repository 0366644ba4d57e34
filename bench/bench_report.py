"""Report generation time for a 60 s run at 1 kHz (60,000 samples).

The folder is simulated once (``hil.sim``, the paper's circle at Ts = 1 ms) or, with
``--synthetic``, written by ``tests.synthetic_folder`` as a run folder with both services' hop
logs (both paths live) measured by hil.analysis.measure. Times ``hil report`` (load, metrics, the
run's measurement, 9-14 figures, report.html/md/json) without the ideal trajectory, median of
repeats, and once with it (a second simulation at Ts/10 dominates that figure).

    python bench/bench_report.py              # simulated folder, 3 repeats, plus --ideal once
    python bench/bench_report.py --quick      # synthetic folder, 1 repeat, no ideal
    python bench/bench_report.py --two-million   # ``hil report`` of 2 M samples, 3 repeats

``--two-million``: the synthetic run folder of 2,000 s at 1 kHz (2 M samples, 33 minutes),
``hil report --no-ideal`` in a subprocess, its wall time and peak resident memory (``wait4``):
median and worst of the repeats (target: under 60 s and 1 GB on a 2-core machine;
tests/test_long_run.py checks only the memory, which load does not move).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _here  # noqa: F401  (this checkout first on sys.path)

from hil.analysis.report.build import build_report, write_report
from hil.analysis.report.ideal import ideal_from_simulator
from hil.folder import load_folder
from tests.scenario_text import circle
from tests.synthetic_folder import write_synthetic_folder

SCENARIO = circle(timing={"ts": 0.001}, run={"duration": 60.0})


def make_folder(root: Path, synthetic: bool) -> Path:
    if synthetic:
        return write_synthetic_folder(root / "synthetic", duration=60.0, rate=1000.0, run=True)
    from hil.scenario import loads_scenario
    from hil.sim import simulate, write_run_folder

    t0 = time.perf_counter()
    result = simulate(loads_scenario(SCENARIO, root))
    print(f"simulated the 60 s folder in {time.perf_counter() - t0:.1f} s")
    return write_run_folder(result, root / "sim")


def once(folder: Path, ideal: bool) -> float:
    t0 = time.perf_counter()
    rep = build_report(load_folder(folder), ideal=ideal_from_simulator if ideal else None)
    write_report(rep, folder)
    return time.perf_counter() - t0


def two_million(root: Path, repeats: int) -> None:
    """``hil report`` of the 2 M-sample synthetic folder in a subprocess: wall s, peak MB."""
    folder = write_synthetic_folder(root / "long", duration=2000.0, rate=1000.0)
    walls, peaks = [], []
    for _ in range(repeats):
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "hil", "report", str(folder), "--no-ideal"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        _, status, usage = os.wait4(proc.pid, 0)
        walls.append(time.monotonic() - t0)
        peaks.append(usage.ru_maxrss / 1024)
        if os.waitstatus_to_exitcode(status) != 0:
            raise SystemExit(f"hil report exited {os.waitstatus_to_exitcode(status)}")
    print(
        f"2 M samples: hil report --no-ideal median {statistics.median(walls):.1f} s (worst "
        f"{max(walls):.1f}), peak {statistics.median(peaks):.0f} MB (worst {max(peaks):.0f}) "
        f"over {repeats}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--synthetic", action="store_true")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--no-ideal", action="store_true", help="skip the timing with --ideal")
    ap.add_argument("--two-million", action="store_true", help="hil report of 2 M samples")
    a = ap.parse_args()
    repeats = a.repeats or (1 if a.quick else 3)
    if a.two_million:
        with tempfile.TemporaryDirectory() as tmp:
            two_million(Path(tmp), repeats)
        return
    with tempfile.TemporaryDirectory() as tmp:
        folder = make_folder(Path(tmp), a.synthetic or a.quick)
        rows = len((folder / "trace.csv").read_text().splitlines()) - 1
        times = [once(folder, ideal=False) for _ in range(repeats)]
        print(
            f"samples {rows}; report without ideal: median {statistics.median(times):.2f} s "
            f"over {repeats} (all: {', '.join(f'{t:.2f}' for t in times)})"
        )
        if not (a.quick or a.no_ideal or a.synthetic):
            seconds = once(folder, True)
            print(f"report with the ideal trajectory (Ts/10 simulation): {seconds:.2f} s")


if __name__ == "__main__":
    main()

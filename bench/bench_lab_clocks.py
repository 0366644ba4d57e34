"""Two-host runs whose clocks differ by seconds against the same runs with equal clocks: the
corrected cross-host figures agree within the offset estimate's uncertainty (docs/lab.md).

Builds two labs of two hosts (root), identical but for their CLOCK_MONOTONIC offsets (+3.2 s
and -1.7 s, then 0 and 0), and runs ``hil run --lab`` (plant on h1, controller on h2, 200 Hz)
``--repeats`` times on each, alternating. Per run: hop_state and hop_cmd_zenoh p50, the offset
estimate's median and uncertainty. Then, per figure, the difference of the medians of the two
labs' p50 against the median uncertainty.

    python bench/bench_lab_clocks.py                    # 3 repeats, 5 s each
    python bench/bench_lab_clocks.py --repeats 5 --duration 10
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import _here  # noqa: F401  (this checkout first on sys.path)

ROOT = Path(__file__).resolve().parents[1]
LABS = {"bcoff": ("h1=3.2", "h2=-1.7"), "bczero": ("h1=0", "h2=0")}
FIGURES = ("hop_state", "hop_cmd_zenoh")


def hil(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hil", *args], capture_output=True, text=True, cwd=ROOT
    )


def one(lab: str, out: Path, duration: float) -> dict:
    args = ["--lab", lab, "--no-can", "--duration", str(duration), "--rate", "200"]
    hil("run", *args, "--quiet", "--no-report", "--out", str(out))
    s = json.loads((out / "summary.json").read_text())
    clock = json.loads((out / "topology.json").read_text())["clock"]
    row = {f: s["timing"][f]["p50_us"] for f in FIGURES}
    row["offset_us"] = clock["offset_ns_median"] / 1e3
    row["uncertainty_us"] = clock["uncertainty_ns_median"] / 1e3
    row["converted"] = clock["converted"]
    return row


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--duration", type=float, default=5.0)
    a = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="bench-lab-clocks-"))
    rows: dict[str, list[dict]] = {lab: [] for lab in LABS}
    try:
        for lab, offsets in LABS.items():
            up = hil(
                "lab", "up", "--name", lab, "--hosts", "2", *[f"--offset={o}" for o in offsets]
            )
            if up.returncode != 0:
                print(up.stderr, file=sys.stderr)
                return 2
        for i in range(a.repeats):
            for lab in LABS:
                rows[lab].append(one(lab, out / f"{lab}-{i}", a.duration))
                print(json.dumps({"lab": lab, **rows[lab][-1]}), flush=True)
    finally:
        for lab in LABS:
            hil("lab", "down", "--name", lab)
    unc = statistics.median(r["uncertainty_us"] for rs in rows.values() for r in rs)
    result = {"runs": rows, "uncertainty_us_median": unc}
    for f in FIGURES:
        a_med = statistics.median(r[f] for r in rows["bcoff"])
        b_med = statistics.median(r[f] for r in rows["bczero"])
        result[f] = {
            "offsets_p50_us": a_med,
            "equal_clocks_p50_us": b_med,
            "difference_us": a_med - b_med,
            "within_uncertainty": abs(a_med - b_med) <= unc,
        }
    print(json.dumps({k: v for k, v in result.items() if k != "runs"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

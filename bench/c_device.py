"""The C device (examples/socketcan_controller.c) measured at the bus on a real SocketCAN vcan0:
one run, its figures and verdict, then ``hil campaign`` (a growing feedback delay toward it)
with the device kept running (``-a``: it re-arms each run's drives).

Where this kernel has no vcan, run it in the QEMU guest (docs/vcan.md); the guest's /tmp is
private, so the folders go under the project's ``runs/``:

    python -m tools.vcan_guest run --timeout 1500 -- python bench/c_device.py

The guest runs Python ~25x slower than its host (TCG): the plant runs at 50 Hz there (the
drives' encoder estimates keep their 10 ms), as in the vcan lane's tests. Prints one table of
figures per run and the campaign's answer; exits with the campaign's code.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import _here  # this checkout first on sys.path

ROOT = _here.ROOT
SOURCE = ROOT / "examples" / "socketcan_controller.c"


def build(dest: Path) -> str:
    gcc = shutil.which("gcc")
    if gcc is None:
        sys.exit("gcc is not installed (Debian package gcc)")
    binary = dest / "socketcan_controller"
    argv = [gcc, "-O2", "-static", "-Wall", "-Wextra", "-Werror", "-o", str(binary), str(SOURCE)]
    subprocess.run(argv, check=True)
    return str(binary)


def figures(run_dir: Path) -> str:
    s = json.loads((run_dir / "summary.json").read_text())
    d, v = s["device"], s["verdict"]
    streams = "; ".join(
        f"{st['name']}: period p50 {st['period']['p50_us'] / 1e3:.2f} ms, jitter p50/p99 "
        f"{st['jitter']['p50_us'] / 1e3:.2f}/{st['jitter']['p99_us'] / 1e3:.2f} ms, "
        f"{st['gap_count']} gaps"
        for st in d["streams"]
    )
    r = d["response"]
    return (
        f"{run_dir.name}: {v['outcome']} ({'; '.join(v['reasons'][:1]) or 'no reason'}); P "
        f"{d['nominal_period_s'] * 1e3:.2f} ms ({d['nominal_period_from']}); {streams}; response "
        f"p50/p99 {r.get('p50_us', 0) / 1e3:.2f}/{r.get('p99_us', 0) / 1e3:.2f} ms; age bound "
        f"max {d['age'].get('max_us', 0) / 1e3:.2f} ms; bus {d['bus']['state_requests']} state "
        f"requests, {d['bus']['armed']} armed"
    )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--channel", default="vcan0")
    p.add_argument("--rate", type=float, default=50.0, help="the plant's rate, Hz")
    p.add_argument("--duration", type=float, default=5.0, help="each run, s")
    p.add_argument("--step", type=float, default=0.01, help="delay added per run, s")
    p.add_argument("--end", type=float, default=0.04, help="largest delay tried, s")
    p.add_argument("--out", default=str(ROOT / "runs" / "c-device"))
    a = p.parse_args()
    out = Path(a.out) if Path(a.out).is_absolute() else ROOT / a.out
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    binary = build(out)
    scenario = out / "scenario.toml"
    scenario.write_text(f'base = "paper_tracking"\n\n[realtime]\nrate = {a.rate:g}\n')
    can = ["--cmd-path", "can", "--can-interface", "socketcan", "--can-channel", a.channel]
    hil = [sys.executable, "-m", "hil"]
    device = subprocess.Popen([binary, "-i", a.channel, "-a"], stdout=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        one = out / "run"
        subprocess.run([*hil, "run", str(scenario), "--controller", "external", *can,
                        "--duration", str(a.duration), "--out", str(one), "--quiet"],
                       cwd=ROOT)  # fmt: skip
        print(figures(one), f"({time.monotonic() - t0:.0f} s)", flush=True)
        camp = out / "campaign"
        code = subprocess.run([*hil, "campaign", str(scenario), *can, "--step", str(a.step),
                               "--end", str(a.end), "--duration", str(a.duration), "--keep-going",
                               "--out", str(camp)], cwd=ROOT).returncode  # fmt: skip
    finally:
        device.terminate()
        print("device:", device.communicate(timeout=10)[0].strip().splitlines()[-1])
    for run_dir in sorted(camp.glob("run-*")):
        print(figures(run_dir))
    print((camp / "campaign.md").read_text().splitlines()[1])
    return code


if __name__ == "__main__":
    raise SystemExit(main())

"""Frames lost on a real wire: ``hil run`` on the CAN path over python-can's ``udp_multicast``,
with nftables dropping every N-th UDP packet to the bus's port in the run's own network
namespace (the scenario's ``[impair]``, docs/impair.md).

    sudo python bench/wire_loss.py [--every 97] [--torque-only] [--duration 6] [--rate 500]
                                   [--out DIR]

Needs root and nftables (``hil run`` makes the namespace and sets the rules; Debian package
``nftables``). Prints what nftables counted (packets matched, dropped), what the bench measured
(``messages.torque_can``: frames lost, commands lost, value mismatches; ``hop_cmd_can`` p50; the
certificate's D and D*; the verdict and ``hil run``'s exit code) as one JSON object.

Without ``--torque-only`` every packet to the bus port may be dropped (the drives' heartbeats and
encoder estimates too), as in the measurement that showed a lost frame shifting the matching.
With it, only the drives' Set_Input_Torque frames: their order on the wire is the order of the
controller's ``can_tx`` rows (one sending thread), so the frames nftables drops are known exactly
(the n-th, 2n-th, ... row) and the script also prints the lost frames and commands the bench
should report (``expected``) and whether the plant received exactly the frames that were not
dropped, in order (``plant_received_the_survivors``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from hil.verdict import EXIT_CODE  # noqa: E402  (a verdict's codes: the command worked)
from protocol.hoplog import read_hoplog  # noqa: E402

GROUP = "239.74.163.2"  # python-can's IPv4 group for udp_multicast (UdpMulticastBus)
SCENARIO = """\
[reference]
kind = "circle"
vd = 0.5
wd = 0.2

[initial]
x = -0.5

[impair]
on = "can"
can_frames = "{frames}"
loss_every = {every}
"""


def scenario_text(every: int, torque_only: bool) -> str:
    """The paper's tracking circle with every ``every``-th CAN packet dropped."""
    return SCENARIO.format(every=every, frames="torque" if torque_only else "all")


def hil_run_args(scenario: Path, out: Path, duration: float, rate: float) -> list[str]:
    """``hil run``'s arguments for the measurement (after ``python -m hil``)."""
    return [
        "run",
        str(scenario),
        "--cmd-path",
        "can",
        "--can-interface",
        "udp_multicast",
        "--can-channel",
        GROUP,
        "--duration",
        f"{duration:g}",
        "--rate",
        f"{rate:g}",
        "--quiet",
        "--no-report",
        "--out",
        str(out),
    ]


def expected_losses(run_dir: Path, every: int) -> dict[str, Any]:
    """What a drop of every ``every``-th Set_Input_Torque frame on the wire must cost, from
    the controller's ``can_tx`` (the frames in wire order) and the window's command count in
    summary.json; and whether the plant's ``cmd_rx`` holds exactly the frames not dropped."""
    summary = json.loads((run_dir / "summary.json").read_text())
    can = summary["messages"]["torque_can"]
    tx = [r for r in read_hoplog(run_dir / "controller.hoplog").table("can_tx") if r["send_ns"]]
    dropped = [r for k, r in enumerate(tx) if k % every == every - 1]
    commands = sorted({r["cmd_seq"] for r in tx if r["cmd_seq"] >= 0})
    # The window's commands are the first `sent` ones (the rest were sent after the plant's
    # last sample); true when sent + sent_after_window covers every command.
    window = set(commands[: can["sent"]])
    in_window = [r for r in dropped if r["cmd_seq"] in window]
    kept = [r for k, r in enumerate(tx) if k % every != every - 1]
    rx = [r for r in read_hoplog(run_dir / "plant.hoplog").table("cmd_rx") if r["path"] == 1]
    survivors = True
    for node in sorted({r["node"] for r in tx}):
        got = [r["tau1"] for r in rx if r["node"] == node]
        want = [r["value"] for r in kept if r["node"] == node]
        survivors &= got == want[: len(got)]  # the plant stops first: a prefix
    return {
        "torque_frames_on_the_wire": len(tx),
        "dropped_torque_frames": len(dropped),
        "dropped_lifecycle_frames": sum(1 for r in dropped if r["cmd_seq"] < 0),
        "window_covers_every_command": can["sent"] + can["sent_after_window"] == len(commands),
        "frames_lost": len(in_window),
        "commands_lost": len({r["cmd_seq"] for r in in_window}),
        "plant_received_the_survivors": bool(survivors),
    }


def figures(summary: dict[str, Any], exit_code: int, stderr: str) -> dict[str, Any]:
    """The numbers the measurement is about, from summary.json and hil run's stderr."""
    can = summary.get("messages", {}).get("torque_can", {})
    hop = summary.get("timing", {}).get("hop_cmd_can") or {}
    cert = summary.get("certificate") or {}
    impair = summary.get("impair") or {}
    verdict = [line for line in stderr.splitlines() if line.startswith("verdict:")]
    return {
        "nft_matched_packets": impair.get("matched_packets"),
        "nft_dropped_packets": impair.get("dropped_packets"),
        "frames_sent": can.get("frames_sent"),
        "frames_lost": can.get("frames_lost"),
        "commands_lost": can.get("lost"),
        "value_mismatches": can.get("value_mismatches"),
        "hop_cmd_can_p50_us": hop.get("p50_us"),
        "d_max_ms": None if cert.get("d_max_s") is None else cert["d_max_s"] * 1e3,
        "d_star_ms": None if cert.get("d_star_s") is None else cert["d_star_s"] * 1e3,
        "certificate_held": cert.get("held"),
        "worst_stall": (cert.get("stalls") or [None])[0],
        "exit_code": exit_code,
        "verdict": verdict[-1] if verdict else "(none printed: exit 0)",
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--every", type=int, default=97, help="drop every N-th packet (default 97)")
    ap.add_argument("--torque-only", action="store_true", help="drop Set_Input_Torque only")
    ap.add_argument("--duration", type=float, default=6.0, help="run length, s (default 6)")
    ap.add_argument("--rate", type=float, default=500.0, help="control rate, Hz (default 500)")
    ap.add_argument("--out", type=Path, default=None, help="run folder (default: a temp one)")
    args = ap.parse_args(argv)
    if args.every < 2:
        ap.error("--every must be at least 2")
    out = args.out or Path(tempfile.mkdtemp(prefix="wire-loss-")) / "run"
    out.parent.mkdir(parents=True, exist_ok=True)
    scenario = out.parent / f"{out.name}-scenario.toml"
    scenario.write_text(scenario_text(args.every, args.torque_only))
    cmd = [sys.executable, "-m", "hil", *hil_run_args(scenario, out, args.duration, args.rate)]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    if proc.returncode not in EXIT_CODE.values() or not (out / "summary.json").is_file():
        sys.stderr.write(proc.stderr[-3000:])
        return proc.returncode or 1
    summary = json.loads((out / "summary.json").read_text())
    facts: dict[str, Any] = {
        "command": " ".join(cmd),
        "every": args.every,
        "torque_only": args.torque_only,
        "run_dir": str(out),
        **figures(summary, proc.returncode, proc.stderr),
    }
    if args.torque_only:
        facts["expected"] = expected_losses(out, args.every)
    print(json.dumps(facts, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

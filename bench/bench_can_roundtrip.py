"""CAN frame round trip between two processes (p50/p99 in microseconds, JSON).

One process echoes every frame it receives (id + 1); this one sends a Set_Input_Torque-sized
frame, waits for the echo and records the round trip on time.monotonic_ns. Repeated runs,
medians of their percentiles: the machine is shared and noisy.

    python bench/bench_can_roundtrip.py                      # default bus (zenoh_can)
    python bench/bench_can_roundtrip.py --quick
    python bench/bench_can_roundtrip.py --interface socketcan --channel vcan0

On zenoh_can it measures with the bitrate model off and at --bitrate (a round trip then holds
two frame times, 2 x 135 bits, on top of the transport).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import time

import _here  # noqa: F401  (this checkout first on sys.path)
import can

_ECHO_READY = "echo-ready"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _open(interface: str, channel: str, bitrate: int | None, endpoint: str | None) -> can.BusABC:
    kw: dict = {"interface": interface, "channel": channel}
    if interface == "zenoh_can":
        kw.update(bitrate=bitrate, endpoint=endpoint)
    return can.Bus(**kw)


def echo(args: argparse.Namespace) -> int:
    stop = False

    def on_signal(signum, frame):
        nonlocal stop
        stop = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    bus = _open(args.interface, args.channel, args.bitrate or None, args.endpoint)
    print(_ECHO_READY, flush=True)
    try:
        while not stop:
            msg = bus.recv(0.1)
            if msg is not None and msg.arbitration_id == 0x02E:
                bus.send(can.Message(arbitration_id=0x02F, data=msg.data, is_extended_id=False))
    finally:
        bus.shutdown()
    return 0


def _percentile(sorted_us: list[float], q: float) -> float:
    i = min(len(sorted_us) - 1, max(0, round(q * (len(sorted_us) - 1))))
    return sorted_us[i]


def measure(args: argparse.Namespace, bitrate: int | None) -> dict:
    endpoint = f"tcp/127.0.0.1:{_free_port()}" if args.interface == "zenoh_can" else None
    argv = [sys.executable, os.path.abspath(__file__), "--echo", "--interface", args.interface,
            "--channel", args.channel, "--bitrate", str(bitrate or 0)]  # fmt: skip
    if endpoint:
        argv += ["--endpoint", endpoint]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        if proc.stdout.readline().strip() != _ECHO_READY:
            raise RuntimeError("echo process did not start")
        bus = _open(args.interface, args.channel, bitrate, endpoint)
        try:
            ping = can.Message(arbitration_id=0x02E, data=bytes(8), is_extended_id=False)
            deadline = time.monotonic() + 20.0
            while True:  # wait for the two members to meet
                bus.send(ping)
                if bus.recv(0.05) is not None:
                    break
                if time.monotonic() > deadline:
                    raise RuntimeError("no echo within 20 s")
            while bus.recv(0.05) is not None:
                pass
            runs = []
            for _ in range(args.repeats):
                rtts = []
                for i in range(args.count):
                    payload = i.to_bytes(8, "little")
                    t0 = time.monotonic_ns()
                    bus.send(can.Message(arbitration_id=0x02E, data=payload, is_extended_id=False))
                    while True:
                        msg = bus.recv(1.0)
                        if msg is None:
                            raise RuntimeError("echo lost")
                        if msg.arbitration_id == 0x02F and bytes(msg.data) == payload:
                            break
                    rtts.append((time.monotonic_ns() - t0) / 1e3)
                rtts.sort()
                runs.append({"p50_us": _percentile(rtts, 0.5), "p99_us": _percentile(rtts, 0.99),
                             "max_us": rtts[-1]})  # fmt: skip
        finally:
            bus.shutdown()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    return {
        "interface": args.interface,
        "channel": args.channel,
        "bitrate_model_bps": bitrate,
        "round_trips_per_run": args.count,
        "runs": len(runs),
        "p50_us_median": statistics.median(r["p50_us"] for r in runs),
        "p99_us_median": statistics.median(r["p99_us"] for r in runs),
        "max_us_max": max(r["max_us"] for r in runs),
        "per_run": runs,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--interface", default="zenoh_can")
    p.add_argument("--channel", default="bench0")
    p.add_argument("--bitrate", type=int, default=1_000_000, help="zenoh_can bitrate model")
    p.add_argument("--endpoint", default=None, help=argparse.SUPPRESS)
    p.add_argument("--count", type=int, default=2000, help="round trips per run")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--quick", action="store_true", help="300 round trips x 3 runs")
    p.add_argument("--out", default=None, help="also write the JSON to this file")
    p.add_argument("--echo", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.echo:
        return echo(args)
    if args.quick:
        args.count, args.repeats = 300, 3
    configs = [None, args.bitrate] if args.interface == "zenoh_can" else [None]
    report = {
        "bench": "can_roundtrip",
        "host": socket.gethostname(),
        "cpu_count": os.cpu_count(),
        "python_can": can.__version__,
        "results": [measure(args, b) for b in configs],
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

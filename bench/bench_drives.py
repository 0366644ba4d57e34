"""The virtual drives serve CAN at bus speed: cyclic rates and request (RTR) latency, JSON.

For each mode (``hil drives``, free running; ``hil emulator --cmd-path can`` waiting in its start
gate) on zenoh_can (bit-time model off): the rate of node 1's cyclic Get_Encoder_Estimates
(configured 100 Hz) and Heartbeat (10 Hz) over a window, and the round trip of a remote request
(Get_Torques, not cyclic, so every answer is the answer) from this process: send the RTR frame,
wait for the answer, on time.monotonic_ns. Repeated runs, medians of their percentiles (the
machine is shared); the same run's plain zenoh_can echo round trip (bench_can_roundtrip) is the
baseline the ratio is quoted against. And how long each mode takes from SIGINT to its exit,
over as many stops as repeats (median and worst).

    python bench/bench_drives.py              # 2000 requests x 5 runs, 5 s rate windows
    python bench/bench_drives.py --quick      # 300 x 3, 3 s
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
import tempfile
import time

import _here  # this checkout first on sys.path (and its ROOT)
import can

HEARTBEAT, ENCODER, TORQUES = 0x01, 0x09, 0x1C
NODE = 1


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _percentile(sorted_us: list[float], q: float) -> float:
    return sorted_us[min(len(sorted_us) - 1, max(0, round(q * (len(sorted_us) - 1))))]


def _start(mode: str, channel: str, endpoint: str, workdir: str) -> subprocess.Popen:
    if mode == "drives":
        argv = ["-m", "hil", "drives", "--no-record", "--can-interface", "zenoh_can"]
        argv += ["--channel", channel, "--can-endpoint", endpoint, "--status-period", "0"]
    else:  # the emulator in its start gate (nobody announces the start)
        argv = ["-m", "hil", "emulator", "paper_tracking", "--cmd-path", "can"]
        argv += ["--can-endpoint", endpoint, "--endpoint", f"tcp/127.0.0.1:{_free_port()}"]
        argv += ["--start-timeout", "600", "--out", workdir]
    return subprocess.Popen(
        [sys.executable, *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        cwd=_here.ROOT,
    )


def _rate(stamps: list[float]) -> float:
    """Frames per second: the least-squares slope of frame index over arrival time (a few
    arrivals bunched by a busy receiver move it far less than first-to-last would)."""
    n = len(stamps)
    if n < 3:
        return 0.0
    tm = sum(stamps) / n
    im = (n - 1) / 2
    var = sum((t - tm) ** 2 for t in stamps)
    return sum((t - tm) * (i - im) for i, t in enumerate(stamps)) / var


def _rates(bus: can.BusABC, window: float) -> dict:
    # Frames queued while this process was busy starting would carry one bunched arrival stamp
    # (zenoh_can stamps arrivals without its bit-time model): start from an empty queue.
    while bus.recv(0.0) is not None:
        pass
    stamps: dict[int, list[float]] = {HEARTBEAT: [], ENCODER: []}
    end = time.monotonic() + window
    while time.monotonic() < end:
        msg = bus.recv(0.05)
        if msg is None or msg.arbitration_id >> 5 != NODE or msg.is_remote_frame:
            continue
        cmd = msg.arbitration_id & 0x1F
        if cmd in stamps:
            stamps[cmd].append(msg.timestamp)
    out = {}
    for cmd, name, hz in ((ENCODER, "encoder", 100.0), (HEARTBEAT, "heartbeat", 10.0)):
        rate = _rate(stamps[cmd])
        out[name] = {
            "frames": len(stamps[cmd]),
            "rate_hz": rate,
            "error_percent": 100.0 * (rate / hz - 1.0),
        }
    return out


def _rtt(bus: can.BusABC, count: int) -> list[float]:
    arb = NODE << 5 | TORQUES
    rtts = []
    for _ in range(count):
        t0 = time.monotonic_ns()
        bus.send(can.Message(arbitration_id=arb, is_remote_frame=True, is_extended_id=False))
        while True:
            msg = bus.recv(1.0)
            if msg is None:
                raise RuntimeError("no answer to a request within 1 s")
            if msg.arbitration_id == arb and not msg.is_remote_frame:
                break
        rtts.append((time.monotonic_ns() - t0) / 1e3)
    rtts.sort()
    return rtts


def measure(mode: str, args: argparse.Namespace) -> dict:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    channel = "hil0" if mode == "emulator" else f"b{os.getpid()}"
    with tempfile.TemporaryDirectory() as workdir:
        proc = _start(mode, channel, endpoint, workdir)
        try:
            bus = can.Bus(interface="zenoh_can", channel=channel, endpoint=endpoint)
            try:
                deadline = time.monotonic() + 60
                while True:  # the drives' heartbeat: they serve the bus
                    msg = bus.recv(0.1)
                    if msg is not None and msg.arbitration_id == NODE << 5 | HEARTBEAT:
                        break
                    if time.monotonic() > deadline or proc.poll() is not None:
                        raise RuntimeError(f"{mode}: no heartbeat within 60 s")
                rates = _rates(bus, args.window)
                runs = []
                for _ in range(args.repeats):
                    rtts = _rtt(bus, args.count)
                    runs.append(
                        {
                            "p50_us": _percentile(rtts, 0.5),
                            "p99_us": _percentile(rtts, 0.99),
                            "max_us": rtts[-1],
                        }
                    )
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
        "mode": mode,
        "rates": rates,
        "rtr_requests_per_run": args.count,
        "runs": len(runs),
        "rtr_p50_us_median": statistics.median(r["p50_us"] for r in runs),
        "rtr_p99_us_median": statistics.median(r["p99_us"] for r in runs),
        "rtr_max_us_max": max(r["max_us"] for r in runs),
        "per_run": runs,
    }


def stop_times(mode: str, repeats: int) -> dict:
    """SIGINT to exit of ``mode``'s process, serving its bus (heard once), ``repeats`` times:
    the median and the worst, ms (docs/can.md quotes ``hil drives``'s; its test only bounds a
    hang)."""
    times = []
    for _ in range(repeats):
        endpoint = f"tcp/127.0.0.1:{_free_port()}"
        channel = "hil0" if mode == "emulator" else f"b{os.getpid()}"
        with tempfile.TemporaryDirectory() as workdir:
            proc = _start(mode, channel, endpoint, workdir)
            try:
                bus = can.Bus(interface="zenoh_can", channel=channel, endpoint=endpoint)
                try:
                    deadline = time.monotonic() + 60
                    while (msg := bus.recv(0.1)) is None or msg.arbitration_id >> 5 != NODE:
                        if time.monotonic() > deadline or proc.poll() is not None:
                            raise RuntimeError(f"{mode}: no frame within 60 s")
                finally:
                    bus.shutdown()
                t0 = time.monotonic()
                os.killpg(proc.pid, signal.SIGINT)
                proc.wait(timeout=30)
                times.append((time.monotonic() - t0) * 1e3)
            finally:
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
    return {"mode": mode, "stops": len(times), "stop_ms_median": statistics.median(times),
            "stop_ms_max": max(times)}  # fmt: skip


def baseline(args: argparse.Namespace) -> dict:
    """The plain zenoh_can echo round trip of this machine, now (bench_can_roundtrip)."""
    from bench import bench_can_roundtrip as rt

    ns = argparse.Namespace(
        interface="zenoh_can", channel="bench0", count=args.count, repeats=args.repeats
    )
    return rt.measure(ns, None)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--count", type=int, default=2000, help="requests per run")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--window", type=float, default=5.0, help="s of cyclic frames counted")
    p.add_argument("--quick", action="store_true", help="300 requests x 3 runs, 3 s windows")
    p.add_argument("--out", default=None, help="also write the JSON to this file")
    args = p.parse_args(argv)
    if args.quick:
        args.count, args.repeats, args.window = 300, 3, 3.0
    results = [measure(mode, args) for mode in ("drives", "emulator")]
    for r in results:
        r["stop"] = stop_times(r["mode"], args.repeats)
    base = baseline(args)
    for r in results:
        r["rtr_p50_over_echo_p50"] = r["rtr_p50_us_median"] / base["p50_us_median"]
        r["rtr_p99_over_echo_p99"] = r["rtr_p99_us_median"] / base["p99_us_median"]
    report = {
        "bench": "drives",
        "host": socket.gethostname(),
        "cpu_count": os.cpu_count(),
        "python_can": can.__version__,
        "results": results,
        "echo_baseline": {k: base[k] for k in ("p50_us_median", "p99_us_median", "max_us_max")},
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

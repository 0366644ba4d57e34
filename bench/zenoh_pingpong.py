"""Raw transport baseline: Zenoh pub/sub ping-pong between two Python processes on loopback, and
a raw UDP socket ping-pong for reference (64-byte payload by default).

Function API for other benchmarks (run from the repository root so ``bench`` is importable)::

    from bench.zenoh_pingpong import zenoh_pingpong, udp_pingpong, baseline
    zenoh_pingpong(n=20_000)  # {"transport": "zenoh", "rtt_p50_us": ..., "rtt_p99_us": ...}
    baseline(n=5_000, repeats=3)  # both, medians over repeats, and their ratio

Command line::

    python bench/zenoh_pingpong.py [--quick] [--n N] [--repeats R] [--payload B] [--out FILE]

The Zenoh side uses the project's own session config (peer, explicit loopback endpoint,
multicast scouting off) and the command QoS (express, REAL_TIME, DROP). The machine is shared:
compare the two transports measured in the same run (the ratio), not absolute numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import select
import signal
import socket
import statistics
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PING_KEY = "bench/pingpong/ping"
PONG_KEY = "bench/pingpong/pong"
REPLY_TIMEOUT_S = 2.0


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _percentiles(rtts_ns: list[int]) -> dict[str, float]:
    ordered = sorted(rtts_ns)
    n = len(ordered)

    def pct(p: float) -> float:
        return ordered[min(n - 1, int(p * n))] / 1000.0

    return {
        "rtt_p50_us": pct(0.50),
        "rtt_p90_us": pct(0.90),
        "rtt_p99_us": pct(0.99),
        "rtt_max_us": ordered[-1] / 1000.0,
        "rtt_mean_us": statistics.fmean(ordered) / 1000.0,
    }


@contextmanager
def _responder(kind: str, arg: str):
    """Start this file as a responder process; stop it by its PID whatever happens."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    proc = subprocess.Popen(
        [sys.executable, str(Path(__file__).resolve()), f"serve-{kind}", arg],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        env=env,
    )
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 60.0)
        line = proc.stdout.readline().decode().split() if ready else []
        if not line or line[0] != "ready":
            raise RuntimeError(f"{kind} responder did not start: {proc.stderr.read1().decode()}")
        yield line[1:]
    finally:
        proc.stdin.close()
        try:
            proc.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()


def _run_pings(
    send: Callable[[bytes], None], recv: Callable[[float], bytes | None], n: int, payload: int
) -> tuple[list[int], int]:
    """n round trips; a reply is matched by its sequence number, late replies are skipped."""
    pad = b"\x00" * max(0, payload - 8)
    rtts: list[int] = []
    lost = 0
    for seq in range(n):
        t0 = time.perf_counter_ns()
        send(struct.pack("<Q", seq) + pad)
        while True:
            reply = recv(REPLY_TIMEOUT_S)
            if reply is None:
                lost += 1
                break
            if struct.unpack_from("<Q", reply)[0] == seq:
                rtts.append(time.perf_counter_ns() - t0)
                break
    return rtts, lost


def zenoh_pingpong(n: int = 20_000, payload: int = 64, warmup: int = 500) -> dict[str, Any]:
    """Zenoh publisher/subscriber round trips between this process and a responder process."""
    import zenoh

    from protocol.zenoh_config import COMMAND_QOS, ZenohSettings, declare_publisher, session_config

    port = _free_tcp_port()
    with _responder("zenoh", str(port)):
        settings = ZenohSettings(mode="peer", connect=(f"tcp/127.0.0.1:{port}",))
        session = zenoh.open(session_config(settings))
        try:
            replies: queue.Queue[bytes] = queue.Queue()
            session.declare_subscriber(PONG_KEY, lambda s: replies.put(s.payload.to_bytes()))
            pub = declare_publisher(session, PING_KEY, COMMAND_QOS)

            def recv(timeout: float) -> bytes | None:
                try:
                    return replies.get(timeout=timeout)
                except queue.Empty:
                    return None

            # Routes take a moment to form: ping until the first reply comes back.
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline:
                pub.put(struct.pack("<Q", 2**64 - 1))
                if recv(0.1) is not None:
                    break
            else:
                raise RuntimeError("zenoh responder never answered")
            _run_pings(pub.put, recv, warmup, payload)
            rtts, lost = _run_pings(pub.put, recv, n, payload)
        finally:
            session.close()
    return {"transport": "zenoh", "n": n, "payload_bytes": payload, "lost": lost,
            **_percentiles(rtts)}  # fmt: skip


def udp_pingpong(n: int = 20_000, payload: int = 64, warmup: int = 500) -> dict[str, Any]:
    """Raw UDP datagram round trips on 127.0.0.1 between this process and a responder."""
    with _responder("udp", "0") as info, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.connect(("127.0.0.1", int(info[0])))

        def recv(timeout: float) -> bytes | None:
            s.settimeout(timeout)
            try:
                return s.recv(65536)
            except TimeoutError:
                return None

        _run_pings(s.send, recv, warmup, payload)
        rtts, lost = _run_pings(s.send, recv, n, payload)
    return {"transport": "udp", "n": n, "payload_bytes": payload, "lost": lost,
            **_percentiles(rtts)}  # fmt: skip


def baseline(n: int = 20_000, payload: int = 64, repeats: int = 3) -> dict[str, Any]:
    """Both ping-pongs ``repeats`` times (interleaved), medians of each figure, and the ratio
    zenoh/udp of the medians (the number to quote on a shared machine)."""
    runs: dict[str, list[dict[str, Any]]] = {"zenoh": [], "udp": []}
    for _ in range(repeats):
        runs["zenoh"].append(zenoh_pingpong(n, payload))
        runs["udp"].append(udp_pingpong(n, payload))
    out: dict[str, Any] = {"n": n, "payload_bytes": payload, "repeats": repeats, "runs": runs}
    for kind, results in runs.items():
        out[kind] = {
            key: statistics.median(r[key] for r in results)
            for key in results[0]
            if key.endswith("_us") or key == "lost"
        }
    out["ratio_zenoh_over_udp"] = {
        key: out["zenoh"][key] / out["udp"][key] for key in ("rtt_p50_us", "rtt_p99_us")
    }
    return out


def _serve_zenoh(port: str) -> None:
    import zenoh

    from protocol.zenoh_config import COMMAND_QOS, ZenohSettings, declare_publisher, session_config

    settings = ZenohSettings(mode="peer", listen=(f"tcp/127.0.0.1:{port}",))
    session = zenoh.open(session_config(settings))
    pub = declare_publisher(session, PONG_KEY, COMMAND_QOS)
    session.declare_subscriber(PING_KEY, lambda s: pub.put(s.payload.to_bytes()))
    print("ready", flush=True)
    sys.stdin.read()
    session.close()


def _serve_udp(port: str) -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", int(port)))
    s.settimeout(0.2)
    print("ready", s.getsockname()[1], flush=True)
    while True:
        try:
            data, peer = s.recvfrom(65536)
            s.sendto(data, peer)
        except TimeoutError:
            # stdin closed (EOF readable) means the pinger is done.
            if select.select([sys.stdin], [], [], 0)[0] and not sys.stdin.read(1):
                return


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] in ("serve-zenoh", "serve-udp"):
        (_serve_zenoh if argv[0] == "serve-zenoh" else _serve_udp)(argv[1])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=20_000, help="round trips per run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--payload", type=int, default=64, help="bytes (>= 8)")
    parser.add_argument("--quick", action="store_true", help="n=2000, repeats=1")
    parser.add_argument("--out", type=Path, help="write the JSON here too")
    args = parser.parse_args(argv)
    if args.quick:
        args.n, args.repeats = 2000, 1
    result = baseline(args.n, max(8, args.payload), args.repeats)
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    sys.exit(main())

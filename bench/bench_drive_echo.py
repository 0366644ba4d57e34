"""What the virtual drives add at the bus: each figure beside a raw python-can peer, same run.

Three processes on one python-can bus: ``hil drives`` (the two virtual ODrives, nodes 0 and 1,
idle), the raw peer (bench/raw_can_peer.py: python-can and the standard library only, nodes 16
and 17) and this process, the measurer. Both devices run the same scheduling (``--scheduling``:
the drives' own ``setup_scheduling``, the peer's stdlib copy of it; this process too).

- **Request to reply** (the drives' answer to an RTR, what odrive-can and odrive_ros2_control
  send): this process sends a remote ``Get_Bus_Voltage_Current`` frame (``--request``) to node
  1 of the drives, waits for the data frame of that id, then the same to the peer's node 16,
  which answers every RTR of its id with one 8-byte frame; alternately, drives first on even
  requests, peer first on odd ones. One figure: CLOCK_MONOTONIC of this process
  (``time.monotonic_ns``) just before ``bus.send`` of the request to just after ``bus.recv``
  returned the answer, in us. A request unanswered within 1 s is counted ``lost``.
- **Period jitter of the cyclic frames**: the drives send Heartbeat and Get_Encoder_Estimates at
  their configured periods (``--heartbeat-ms``, ``--encoder-ms``); the peer sends frames of the
  same sizes at the same periods (``--cyclic-mode loop``: one thread on absolute deadlines, or
  python-can's ``send_periodic``). One figure per frame id: ``|t[i+1] - t[i] - T|`` in us, t the
  bus's receive stamp of each frame in this process (``msg.timestamp``: the kernel's on SocketCAN
  and udp_multicast, the Zenoh callback's on zenoh_can), T the configured period; both nodes'
  samples pooled per kind. A lost frame reads as a period of 2T: its jitter is T.

Each repeat starts both devices afresh, one after the other, the second once the first is heard
on the bus, the one first on the bus alternating from repeat to repeat (drives first on even
repeats, ``first_on_bus`` in the JSON). Every frame reaches all three processes, and on
udp_multicast the kernel wakes a group's sockets in a fixed order given by when each joined:
on two cores, with all three at SCHED_FIFO, the one woken second waits for a core while the one
woken first and the measurer (reading its own request back) run. Which device joined first
moved the request-to-reply ratio by 0.2-0.4 here; alternating puts each device in each place
equally. Then a window of cyclic frames (nothing else sent), then the request pairs. Per repeat
p50 and p99 (nearest rank) of each figure; the table quotes the median over repeats and the
ratio drives / peer, against the target of 1.2. The machine is shared: run it on a quiet one
and quote the medians.

    python bench/bench_drive_echo.py                         # zenoh_can, 6 x (5 s, 2000 pairs)
    python bench/bench_drive_echo.py --quick                 # 4 x (3 s, 300 pairs)
    python bench/bench_drive_echo.py --interface udp_multicast   # re-runs itself in a private
                                                                 # network namespace (root)
    python -m tools.vcan_guest run -- python bench/bench_drive_echo.py --interface socketcan \\
        --channel vcan0 --quick --encoder-ms 50 --control-rate 100   # QEMU guest: emulated,
                                                                      # for information only
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import itertools
import json
import os
import shlex
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import can  # noqa: E402

from bench import raw_can_peer  # noqa: E402
from protocol.can.bus_factory import CanSettings, in_private_netns  # noqa: E402
from protocol.can.codec import Cmd, frame_id  # noqa: E402

PEER = Path(raw_can_peer.__file__)
DRIVE_NODES = (CanSettings().node_left, CanSettings().node_right)  # hil drives' defaults
PEER_NODES = (16, 17)
NODES = {"drives": DRIVE_NODES, "peer": PEER_NODES}
# Which device joins the bus first, by repeat: alternated (module docstring)
JOIN_ORDERS = ("drives", "peer")
GROUP = "239.74.163.2"  # python-can's IPv4 group for udp_multicast
REQUESTS = {
    "bus_voltage_current": Cmd.GET_BUS_VOLTAGE_CURRENT,
    "torques": Cmd.GET_TORQUES,
    "iq": Cmd.GET_IQ,
    "temperature": Cmd.GET_TEMPERATURE,
    "error": Cmd.GET_ERROR,
}
CYCLIC = {"heartbeat": Cmd.HEARTBEAT, "encoder": Cmd.GET_ENCODER_ESTIMATES}
ANSWER_TIMEOUT_S = 1.0
TARGET = 1.2  # drives / peer, p50 and p99: what the bench may add at the bus
NETNS_ENV = "HIL_BENCH_IN_NETNS"
# what the drives' summary says they did (a check that they answered and sent)
DRIVES_COUNTERS = ("frames_in", "frames_out", "requests", "send_errors", "socket_drops")


@dataclass(frozen=True)
class BusConfig:
    interface: str = "zenoh_can"
    channel: str = "bench_echo"
    endpoint: str | None = None  # zenoh_can only
    bitrate: int = 1_000_000  # the devices' zenoh_can bit-time model (the measurer's is off)


# --- the figures (pure) ---------------------------------------------------------------------------
def percentile(sorted_values: list[float], q: float) -> float:
    """Nearest rank of an ascending list (a measured value, never an interpolation)."""
    n = len(sorted_values)
    return sorted_values[min(n - 1, max(0, round(q * (n - 1))))]


def period_jitter_us(stamps_s: list[float], period_s: float) -> list[float]:
    """``|t[i+1] - t[i] - T|`` in us for consecutive receive stamps of one frame id."""
    return [abs((b - a) - period_s) * 1e6 for a, b in itertools.pairwise(stamps_s)]


def summarize(values_us: list[float]) -> dict[str, float | int]:
    s = sorted(values_us)
    if not s:
        return {"count": 0}
    return {
        "count": len(s),
        "p50_us": percentile(s, 0.5),
        "p99_us": percentile(s, 0.99),
        "max_us": s[-1],
    }


# --- measuring on a bus -----------------------------------------------------------------------
def drain(bus: can.BusABC) -> None:
    while bus.recv(0.0) is not None:
        pass


def collect_stamps(bus: can.BusABC, ids: set[int], window_s: float) -> dict[int, list[float]]:
    """The receive stamps (``msg.timestamp``, s) of every data frame of ``ids`` for
    ``window_s``, from an emptied queue (frames queued before would be read late)."""
    drain(bus)
    stamps: dict[int, list[float]] = {i: [] for i in ids}
    end = time.monotonic() + window_s
    while (left := end - time.monotonic()) > 0:
        msg = bus.recv(min(left, 0.05))
        if msg is not None and not msg.is_remote_frame and msg.arbitration_id in stamps:
            stamps[msg.arbitration_id].append(msg.timestamp)
    return stamps


def request(bus: can.BusABC, arb: int, timeout_s: float = ANSWER_TIMEOUT_S) -> float | None:
    """One RTR of ``arb`` to its answer (the data frame of that id): us on this process'
    CLOCK_MONOTONIC, send to receive; None when none came within ``timeout_s``."""
    t0 = time.monotonic_ns()
    bus.send(can.Message(arbitration_id=arb, is_remote_frame=True, is_extended_id=False))
    give_up = t0 + int(timeout_s * 1e9)
    while (left := give_up - time.monotonic_ns()) > 0:
        msg = bus.recv(left / 1e9)
        if msg is not None and msg.arbitration_id == arb and not msg.is_remote_frame:
            return (time.monotonic_ns() - t0) / 1e3
    return None


def round_trips(bus: can.BusABC, arbs: list[int], count: int) -> dict[int, dict[str, Any]]:
    """``count`` requests to each id of ``arbs``, interleaved (the first id first on even
    rounds, reversed on odd ones): {id: {"rtt_us": [...], "lost": n}}."""
    out: dict[int, dict[str, Any]] = {a: {"rtt_us": [], "lost": 0} for a in arbs}
    drain(bus)
    for i in range(count):
        for arb in arbs if i % 2 == 0 else arbs[::-1]:
            rtt = request(bus, arb)
            if rtt is None:
                out[arb]["lost"] += 1
                drain(bus)  # a late answer must not be read as the next one
            else:
                out[arb]["rtt_us"].append(rtt)
    return out


# --- the processes ------------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen) -> None:
    """SIGINT to the process group, by PID; SIGKILL after 10 s."""
    if proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def peer_argv(bus: BusConfig, answer: list[str], cyclic: list[str], *extra: str) -> list[str]:
    argv = [sys.executable, str(PEER), "--interface", bus.interface, "--channel", bus.channel]
    argv += ["--bitrate", str(bus.bitrate)]
    if bus.endpoint:
        argv += ["--endpoint", bus.endpoint]
    for a in answer:
        argv += ["--answer", a]
    for c in cyclic:
        argv += ["--cyclic", c]
    return argv + list(extra)


@contextlib.contextmanager
def started(
    argv: list[str],
    stdout: IO[str] | int,
    stderr: IO[str] | int | None,
    ready: str | None = None,
    cwd: Path = ROOT,
) -> Iterator[subprocess.Popen]:
    """A process in its own group (stopped by PID on the way out); with ``ready``, after it
    printed that line."""
    proc = subprocess.Popen(
        argv, stdout=stdout, stderr=stderr, text=True, start_new_session=True, cwd=cwd
    )
    try:
        if ready is not None and proc.stdout is not None:
            line = proc.stdout.readline().strip()
            if line != ready:
                raise RuntimeError(f"{argv[1]} did not start (said {line!r})")
        yield proc
    finally:
        _stop(proc)


def open_measurer_bus(bus: BusConfig) -> can.BusABC:
    """This process' bus: zenoh_can with the bit-time model off (frames stamped on arrival)."""
    kw: dict[str, Any] = {"interface": bus.interface, "channel": bus.channel}
    if bus.interface == "zenoh_can":
        kw["endpoint"] = bus.endpoint
    return can.Bus(**kw)


def wait_for(bus: can.BusABC, ids: set[int], procs: list[subprocess.Popen], timeout: float) -> None:
    """Until a frame of each id was heard (the device serves the bus)."""
    missing = set(ids)
    deadline = time.monotonic() + timeout
    while missing:
        msg = bus.recv(0.1)
        if msg is not None:
            missing.discard(msg.arbitration_id)
        if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
            raise RuntimeError(f"no frame of {sorted(hex(i) for i in missing)} in {timeout} s")


# --- one measurement -------------------------------------------------------------------------
def measure(args: argparse.Namespace) -> dict[str, Any]:
    endpoint = f"tcp/127.0.0.1:{_free_port()}" if args.interface == "zenoh_can" else None
    bus_cfg = BusConfig(args.interface, args.channel, endpoint, args.bitrate)
    cmd = REQUESTS[args.request]
    periods_ms = {"heartbeat": args.heartbeat_ms, "encoder": args.encoder_ms}
    options = {
        "--can-interface": args.interface,
        "--channel": args.channel,
        "--status-period": 0,
        "--heartbeat-ms": args.heartbeat_ms,
        "--encoder-ms": args.encoder_ms,
        "--control-rate": args.control_rate,
        "--scheduling": args.scheduling,
    }
    if args.interface == "zenoh_can":
        options.update({"--can-endpoint": endpoint, "--bitrate": args.bitrate})
    drives_argv = [sys.executable, "-m", "hil", "drives"]
    # The light form's flag since hil drives records by default; an older checkout has none.
    commands = (args.drives_root / "hil" / "commands").glob("*.py")
    if any("--no-record" in f.read_text() for f in commands):
        drives_argv.append("--no-record")
    drives_argv += [str(x) for kv in options.items() for x in kv]
    cyclic = [f"{frame_id(n, CYCLIC[k])}:{ms}" for n in PEER_NODES for k, ms in periods_ms.items()]
    answer = [str(frame_id(PEER_NODES[0], cmd))]
    peer_extra = ["--cyclic-mode", args.cyclic_mode, "--scheduling", args.scheduling]
    series = {
        (who, kind): [frame_id(n, CYCLIC[kind]) for n in nodes]
        for who, nodes in (("drives", DRIVE_NODES), ("peer", PEER_NODES))
        for kind in CYCLIC
    }
    targets = {"drives": frame_id(DRIVE_NODES[1], cmd), "peer": frame_id(PEER_NODES[0], cmd)}
    # This process' bus first: on zenoh_can it owns the well-known endpoint, both devices
    # connect to it and each is one hop from it (a device that owned it would be the
    # other's first route).
    bus = open_measurer_bus(bus_cfg)
    runs, drives_summaries, sched_errors = [], [], []
    try:
        for k in range(args.repeats):
            first = JOIN_ORDERS[k % 2]
            with tempfile.TemporaryFile("w+") as drives_out, contextlib.ExitStack() as stack:
                procs = {}
                for who in (first, *(w for w in ("drives", "peer") if w != first)):
                    # Each device on the bus before the next starts (module docstring).
                    if who == "drives":
                        procs[who] = stack.enter_context(
                            started(
                                drives_argv, drives_out, subprocess.STDOUT, cwd=args.drives_root
                            )
                        )
                    else:
                        peer_cmd = peer_argv(bus_cfg, answer, cyclic, *peer_extra)
                        procs[who] = stack.enter_context(
                            started(peer_cmd, subprocess.PIPE, None, raw_can_peer.READY)
                        )
                    ids = {frame_id(n, Cmd.HEARTBEAT) for n in NODES[who]}
                    wait_for(bus, ids, list(procs.values()), timeout=120.0)
                sched_errors = raw_can_peer.apply_scheduling(args.scheduling)
                round_trips(bus, list(targets.values()), args.warmup)
                gc.disable()  # no collection of this process inside a figure
                try:
                    run = one_repeat(bus, series, periods_ms, targets, args)
                finally:
                    gc.enable()
                runs.append({"first_on_bus": first, **run})
                stack.close()  # the processes stop: the drives print their summary
                drives_out.seek(0)
                drives_summaries.append(_last_json(drives_out.read()).get("summary", {}))
    finally:
        bus.shutdown()
    counters = {
        k: _sum_or_none([d.get("can", {}).get(k) for d in drives_summaries])
        for k in DRIVES_COUNTERS
    }
    return {
        "bus": asdict(bus_cfg),
        "request": args.request,
        "periods_ms": periods_ms,
        "runs": runs,
        "measurer_scheduling_errors": sched_errors,
        "drives_can_counters": counters,
        "drives_scheduling": drives_summaries[-1].get("scheduling") if drives_summaries else None,
    }


def one_repeat(
    bus: can.BusABC,
    series: dict[tuple[str, str], list[int]],
    periods_ms: dict[str, float],
    targets: dict[str, int],
    args: argparse.Namespace,
) -> dict[str, Any]:
    """One repeat's figures: a window of cyclic frames, then the request pairs."""
    stamps = collect_stamps(bus, {i for ids in series.values() for i in ids}, args.window)
    period_s = {k: ms / 1000.0 for k, ms in periods_ms.items()}
    jitter = {
        f"{who}/{kind}": summarize(
            [j for i in ids for j in period_jitter_us(stamps[i], period_s[kind])]
        )
        for (who, kind), ids in series.items()
    }
    rtts = round_trips(bus, list(targets.values()), args.count)
    rtr = {
        who: {**summarize(rtts[arb]["rtt_us"]), "lost": rtts[arb]["lost"]}
        for who, arb in targets.items()
    }
    return {"rtr": rtr, "jitter": jitter}


def _sum_or_none(values: list[Any]) -> int | None:
    return None if not values or any(v is None for v in values) else sum(values)


def _last_json(text: str) -> dict[str, Any]:
    for line in reversed(text.splitlines()):
        if line.startswith("{"):
            with contextlib.suppress(ValueError):
                return json.loads(line)
    return {}


# --- the report --------------------------------------------------------------------------------
def _median(runs: list[dict[str, Any]], path: tuple[str, ...], key: str) -> float | None:
    values = []
    for r in runs:
        node: Any = r
        for p in path:
            node = node[p]
        if key in node:
            values.append(node[key])
    return statistics.median(values) if values else None


def rows(result: dict[str, Any], first_on_bus: str | None = None) -> list[dict[str, Any]]:
    """One row per figure: the medians over repeats of drives and peer, their ratios (over the
    repeats with ``first_on_bus`` first on the bus only, when given)."""
    runs = [r for r in result["runs"] if first_on_bus in (None, r.get("first_on_bus"))]
    figures = [("request -> reply", ("rtr", "drives"), ("rtr", "peer"))]
    figures += [
        (f"{kind} period jitter", ("jitter", f"drives/{kind}"), ("jitter", f"peer/{kind}"))
        for kind in CYCLIC
    ]
    out = []
    for name, d_path, p_path in figures:
        row: dict[str, Any] = {"figure": name}
        for q in ("p50_us", "p99_us"):
            d, p = _median(runs, d_path, q), _median(runs, p_path, q)
            row[f"drives_{q}"], row[f"peer_{q}"] = d, p
            row[f"ratio_{q[:3]}"] = d / p if d is not None and p else None
        ratios = [row["ratio_p50"], row["ratio_p99"]]
        row["met"] = None if None in ratios else all(r <= TARGET for r in ratios)
        out.append(row)
    return out


def table(result: dict[str, Any]) -> str:
    def num(x: float | None, fmt: str) -> str:
        return "-" if x is None else format(x, fmt)

    head = (
        f"{'figure':<26}{'drives p50':>11}{'p99':>9}{'peer p50':>10}{'p99':>9}"
        f"{'ratio p50':>11}{'p99':>7}  <= {TARGET}x"
    )
    lines = [head, "-" * len(head)]
    for r in result["rows"]:
        met = {True: "yes", False: "NO", None: "-"}[r["met"]]
        lines.append(
            f"{r['figure'] + ' (us)':<26}{num(r['drives_p50_us'], '.0f'):>11}"
            f"{num(r['drives_p99_us'], '.0f'):>9}{num(r['peer_p50_us'], '.0f'):>10}"
            f"{num(r['peer_p99_us'], '.0f'):>9}{num(r['ratio_p50'], '.2f'):>11}"
            f"{num(r['ratio_p99'], '.2f'):>7}  {met}"
        )
    lost = {
        who: sum(run["rtr"][who]["lost"] for run in result["runs"]) for who in ("drives", "peer")
    }
    lines.append(f"unanswered requests: drives {lost['drives']}, peer {lost['peer']}")
    for first in JOIN_ORDERS:
        r = rows(result, first)[0]
        if r["ratio_p50"] is not None:
            lines.append(
                f"request -> reply, repeats with the {first} first on the bus: ratio p50 "
                f"{r['ratio_p50']:.2f}, p99 {r['ratio_p99']:.2f}"
            )
    return "\n".join(lines)


# --- udp_multicast: in a private network namespace ---------------------------------------------
def reexec_in_netns(argv: list[str]) -> int:
    """This benchmark again, in a private network namespace with multicast on its loopback
    (udp_multicast sends to a group on the default interface: nothing may leave the host)."""
    unshare = shutil.which("unshare")
    if unshare is None or os.geteuid() != 0:
        print(
            "error: udp_multicast runs in a private network namespace: root and unshare "
            "(util-linux) needed",
            file=sys.stderr,
        )
        return 2
    me = " ".join(shlex.quote(a) for a in [sys.executable, os.path.abspath(__file__), *argv])
    script = (
        "set -e; ip link set lo up; ip link set lo multicast on; "
        f"ip route add 224.0.0.0/4 dev lo; exec {me}"
    )
    env = {**os.environ, NETNS_ENV: "1"}
    env["PATH"] = env.get("PATH", "") + ":/usr/sbin:/sbin"
    return subprocess.call([unshare, "-n", "sh", "-c", script], env=env)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--interface", default="zenoh_can", choices=("zenoh_can", "udp_multicast", "socketcan")
    )
    p.add_argument(
        "--channel",
        default=None,
        help="bench_echo (zenoh_can), 239.74.163.2 (udp_multicast), vcan0 (socketcan)",
    )
    p.add_argument(
        "--bitrate",
        type=int,
        default=1_000_000,
        help="the devices' zenoh_can bit-time model (the measurer's: off)",
    )
    p.add_argument("--request", choices=sorted(REQUESTS), default="bus_voltage_current")
    p.add_argument("--count", type=int, default=2000, help="request pairs per repeat")
    p.add_argument("--warmup", type=int, default=50, help="request pairs before the first repeat")
    p.add_argument("--window", type=float, default=5.0, help="s of cyclic frames per repeat")
    p.add_argument(
        "--repeats", type=int, default=6, help="even: each device first on the bus in half"
    )
    p.add_argument("--heartbeat-ms", type=float, default=100.0)
    p.add_argument("--encoder-ms", type=float, default=10.0)
    p.add_argument("--control-rate", type=float, default=1000.0, help="the drives' plant, Hz")
    p.add_argument(
        "--cyclic-mode",
        choices=("loop", "send_periodic"),
        default="loop",
        help="the peer's periodic sender (bench/raw_can_peer.py)",
    )
    p.add_argument(
        "--scheduling",
        choices=("fifo", "other"),
        default="fifo",
        help="of the drives, the peer and this process (drives' default)",
    )
    p.add_argument(
        "--drives-root",
        type=Path,
        default=ROOT,
        help="the checkout whose `python -m hil drives` runs (e.g. an older commit's\n"
        "git archive, for a before/after); default: this one",
    )
    p.add_argument("--quick", action="store_true", help="4 repeats of 3 s and 300 pairs")
    p.add_argument("--out", default=None, help="also write the JSON to this file")
    args = p.parse_args(argv)
    if args.interface == "udp_multicast" and not in_private_netns():
        if os.environ.get(NETNS_ENV):
            print("error: not in a private network namespace after unshare", file=sys.stderr)
            return 2
        return reexec_in_netns(sys.argv[1:] if argv is None else argv)
    if args.channel is None:
        args.channel = {"zenoh_can": "bench_echo", "udp_multicast": GROUP}.get(
            args.interface, "vcan0"
        )
    if args.quick:
        args.repeats, args.window, args.count = 4, 3.0, 300
    result = measure(args)
    result["rows"] = rows(result)
    report = {
        "bench": "drive_echo",
        "host": socket.gethostname(),
        "cpu_count": os.cpu_count(),
        "loadavg": os.getloadavg(),
        "in_vcan_guest": bool(os.environ.get("HIL_IN_VCAN_GUEST")),
        "python_can": can.__version__,
        "scheduling": args.scheduling,
        "cyclic_mode": args.cyclic_mode,
        "repeats": args.repeats,
        "window_s": args.window,
        "pairs_per_repeat": args.count,
        "drives_root": str(args.drives_root),
        **result,
    }
    text = json.dumps(report, indent=2)
    print(text)
    print(table(result))
    if report["in_vcan_guest"]:
        print("(QEMU guest: software-emulated CPU and bus, figures for information only)")
    if args.out:
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

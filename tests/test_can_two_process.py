"""Two real processes over one CAN bus: the host arms both drives through the lifecycle and
sends torques; the other process is ``hil drives`` (the robot and its two virtual drives) and
answers with heartbeats and encoder estimates that the host decodes. Runs over the default bus
(zenoh_can) and, marked ``vcan``, over SocketCAN vcan0 (the QEMU guest lane, at 50 Hz). The
default bus holds no socket off loopback."""

from __future__ import annotations

import ipaddress
import json
import os
import select
import signal
import subprocess
import time
import uuid
from pathlib import Path

import pytest

from tests.procs import free_tcp_port

INET_TABLES = ("tcp", "tcp6", "udp", "udp6", "udplite", "udplite6", "raw", "raw6")
OTHER_TABLES = ("unix", "netlink", "packet")


def _bus_args(kind: str) -> list[str]:
    if kind == "zenoh":
        channel = f"t{uuid.uuid4().hex[:8]}"
        endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        return ["--interface", "zenoh_can", "--channel", channel, "--endpoint", endpoint]
    if not Path("/sys/class/net/vcan0").exists():
        pytest.fail(
            "vcan0 does not exist: run the vcan lane where the kernel has it "
            "(modprobe vcan; ip link add dev vcan0 type vcan; ip link set up vcan0) "
            "or inside the QEMU guest, or deselect it with -m 'not vcan'"
        )
    return ["--interface", "socketcan", "--channel", "vcan0"]


def _addr(hexaddr: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    host = hexaddr.split(":")[0]
    if len(host) == 8:
        return ipaddress.IPv4Address(bytes.fromhex(host)[::-1])
    raw = b"".join(bytes.fromhex(host[i : i + 8])[::-1] for i in range(0, 32, 8))
    return ipaddress.IPv6Address(raw)


def _loopback(addr) -> bool:
    if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
        addr = addr.ipv4_mapped
    return addr.is_loopback


def socket_report(pid: int) -> tuple[list[tuple[str, str, str]], list[str]]:
    """(inet sockets as (table, local, remote), problems) of process ``pid``.

    Every socket fd of the process must be a unix or netlink socket or an inet socket whose
    local address is loopback and whose peer is loopback or unset (a listener)."""
    inodes = _socket_inodes(pid)
    inet, problems, seen = [], [], set()
    for table in INET_TABLES:
        path = Path(f"/proc/{pid}/net/{table}")
        if not path.exists():
            continue
        for line in path.read_text().splitlines()[1:]:
            cols = line.split()
            if len(cols) < 10 or cols[9] not in inodes:
                continue
            local, remote = _addr(cols[1]), _addr(cols[2])
            seen.add(cols[9])
            inet.append((table, str(local), str(remote)))
            if not _loopback(local) or not (_loopback(remote) or remote.is_unspecified):
                problems.append(f"{table} {local} -> {remote}")
    for table in OTHER_TABLES:
        path = Path(f"/proc/{pid}/net/{table}")
        if path.exists():
            for line in path.read_text().splitlines()[1:]:
                cols = line.split()
                seen.update(c for c in cols if c in inodes)
    # A socket closed between the fd listing and the tables' reading is in neither any more:
    # only one still open and in no table is a socket of a kind the scan does not know.
    unknown = (inodes - seen) & _socket_inodes(pid)
    problems += [f"socket inode {i} in no known table" for i in sorted(unknown)]
    return inet, problems


def _socket_inodes(pid: int) -> set[str]:
    """The inodes of the sockets process ``pid`` has open now."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue  # the fd closed meanwhile
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    return inodes


def _wait_ready(proc: subprocess.Popen, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        ready, _, _ = select.select([proc.stdout], [], [], 0.2)
        if ready:
            line = proc.stdout.readline()
            if line.startswith("hil drives:"):
                return
        if proc.poll() is not None:
            break
    raise AssertionError(f"drives process not ready: {proc.stderr.read() if proc.stderr else ''}")


@pytest.mark.realtime
@pytest.mark.parametrize("kind", ["zenoh", pytest.param("vcan", marks=pytest.mark.vcan)])
def test_can_two_processes_run_the_drive_lifecycle(spawn, kind):
    bus = _bus_args(kind)
    # the vcan guest runs Python ~25x slower: plant and drives at 50 Hz, encoders at 20 Hz, and
    # no drive watchdog (hil drives' default 1 s): a pause of the slowed host is not a fault here
    slow = [] if kind == "zenoh" else ["--control-rate", "50", "--encoder-ms", "50"]
    slow += [] if kind == "zenoh" else ["--watchdog-timeout", "0"]
    drives = spawn.python(
        ["-m", "hil", "drives", "--no-record", *_drives_bus(bus), "--status-period", "0", *slow],
        text=True,
    )
    _wait_ready(drives, timeout=120.0)
    cycles = 150 if kind == "zenoh" else 40
    host = spawn.python(
        ["-m", "protocol.can.drive_link", *bus, "--torque", "0.05", "--cycles", str(cycles)],
        text=True,
    )
    host_sockets: list = []
    problems: list[str] = []
    deadline = time.monotonic() + 180.0
    while host.poll() is None and time.monotonic() < deadline:
        if kind == "zenoh":
            try:
                inet, bad = socket_report(host.pid)
            except OSError:
                break  # exited between poll() and the scan
            host_sockets += inet
            problems += bad
        time.sleep(0.05)
    out, err = host.communicate(timeout=30)
    assert host.returncode == 0, err
    result = json.loads(out.strip().splitlines()[-1])
    assert result["armed"] and result["phase_after_commands"] == "active", result
    assert result["torque_cycles"] == cycles and result["idle_confirmed"]
    assert result["rejections"] == {}
    for node, sign in (("1", 1.0), ("0", -1.0)):  # right +torque, left -torque
        view = result["drives"][node]
        assert view["heartbeats"] >= 2 and view["estimates"] >= 5, view
        assert view["axis_state"] == 1 and view["axis_error"] == 0  # IDLE after disarm
        assert sign * view["vel_rev_s"] > 0, view  # the torque acted, seen through estimates

    if kind == "zenoh":
        inet, bad = socket_report(drives.pid)
        assert inet and host_sockets, "no inet socket seen: the scan is not looking"
        assert bad == [] and problems == []

    drives.send_signal(signal.SIGINT)
    out, err = drives.communicate(timeout=30)
    assert drives.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])["summary"]["can"]
    assert summary["rejections"] == {}, summary
    for node in ("0", "1"):
        assert summary["drives"][node]["axis_state"] == 1
        assert summary["drives"][node]["control_mode"] == 1  # TORQUE_CONTROL


def _drives_bus(bus: list[str]) -> list[str]:
    """drive_link's bus options as hil drives spells them."""
    renamed = {"--interface": "--can-interface", "--endpoint": "--can-endpoint"}
    return [renamed.get(a, a) for a in bus]

"""The Zenoh configuration opens no socket off loopback (asserted from /proc, not assumed).

What is allowed, precisely, for every socket the process owns (found through the inodes of
``/proc/<pid>/fd`` in ``/proc/<pid>/net/{tcp,tcp6,udp,udp6,raw,raw6}``):

- TCP listening sockets bound to a loopback address (127.0.0.0/8, ::1, ::ffff:127.x);
- TCP connections whose local and remote addresses are both loopback;
- a TCP socket that is neither bound nor connected (0.0.0.0:0 <-> 0.0.0.0:0): it can send
  nothing, and Zenoh briefly holds such sockets while it connects or closes;
- no UDP and no raw socket at all: with multicast scouting off Zenoh needs none, so any would
  be a leak (a multicast scout, an all-interfaces UDP listener).
"""

from __future__ import annotations

import ipaddress
import os
import subprocess
import textwrap
from dataclasses import dataclass

from tests.procs import free_tcp_port
from tests.test_zenoh_exchange import wait_for_line

TCP_LISTEN = "0A"
PROTOCOLS = ("tcp", "tcp6", "udp", "udp6", "raw", "raw6")


@dataclass(frozen=True)
class InetSocket:
    proto: str
    local: tuple[ipaddress.IPv4Address | ipaddress.IPv6Address, int]
    remote: tuple[ipaddress.IPv4Address | ipaddress.IPv6Address, int]
    state: str


def _address(field: str) -> tuple[ipaddress.IPv4Address | ipaddress.IPv6Address, int]:
    hex_ip, hex_port = field.split(":")
    raw = bytes.fromhex(hex_ip)
    # The kernel prints each 32-bit word in host (little-endian) order.
    packed = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return ipaddress.ip_address(packed), int(hex_port, 16)


def process_sockets(pid: int) -> list[InetSocket]:
    """Every TCP/UDP/raw socket (IPv4 and IPv6) owned by process ``pid``."""
    inodes = set()
    fd_dir = f"/proc/{pid}/fd"
    for fd in os.listdir(fd_dir):
        try:
            target = os.readlink(os.path.join(fd_dir, fd))
        except FileNotFoundError:  # closed while we looked
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for proto in PROTOCOLS:
        with open(f"/proc/{pid}/net/{proto}") as table:
            next(table)
            for line in table:
                cols = line.split()
                if cols[9] in inodes:
                    found.append(InetSocket(proto, _address(cols[1]), _address(cols[2]), cols[3]))
    return found


def _is_loopback(ip: ipaddress.IPv4Address | ipaddress.IPv6Address) -> bool:
    mapped = getattr(ip, "ipv4_mapped", None)
    return (mapped or ip).is_loopback


def off_loopback(sockets: list[InetSocket]) -> list[InetSocket]:
    """The sockets the module docstring does not allow."""
    bad = []
    for s in sockets:
        if not s.proto.startswith("tcp"):
            bad.append(s)
        elif s.state == TCP_LISTEN:
            if not _is_loopback(s.local[0]):
                bad.append(s)
        elif s.local[1] == 0 and s.remote[1] == 0 and s.local[0].is_unspecified:
            continue
        elif not (_is_loopback(s.local[0]) and _is_loopback(s.remote[0])):
            bad.append(s)
    return bad


SESSIONS = textwrap.dedent(
    """
    import sys, time
    import zenoh
    from protocol.zenoh_config import ZenohSettings, session_config

    router_port, peer_port = sys.argv[1], sys.argv[2]
    def open_(**kw):
        return zenoh.open(session_config(ZenohSettings(**kw)))
    router = open_(mode="router", listen=(f"tcp/127.0.0.1:{router_port}",))
    client = open_(mode="client", connect=(f"tcp/127.0.0.1:{router_port}",))
    peer_a = open_(mode="peer", listen=(f"tcp/127.0.0.1:{peer_port}",))
    peer_b = open_(mode="peer", connect=(f"tcp/127.0.0.1:{peer_port}",))  # default listen

    def link_up(sender, receiver, key):
        got = []
        sub = receiver.declare_subscriber(key, lambda s: got.append(1))
        deadline = time.monotonic() + 20
        while not got and time.monotonic() < deadline:
            sender.put(key, b"x")
            time.sleep(0.05)
        sub.undeclare()
        return bool(got)

    ok = link_up(client, router, "hil/t/a") and link_up(peer_b, peer_a, "hil/t/b")
    print("ready" if ok else "no-link", flush=True)
    sys.stdin.read()
    for s in (peer_b, peer_a, client, router):
        s.close()
    """
)

LEAKY = textwrap.dedent(
    """
    import socket, sys
    u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); u.bind(("0.0.0.0", 0))
    t = socket.socket(); t.bind(("0.0.0.0", 0)); t.listen()
    ok = socket.socket(); ok.bind(("127.0.0.1", 0)); ok.listen()
    print("ready", flush=True)
    sys.stdin.read()
    """
)


def test_zenoh_peer_client_router_sockets_stay_on_loopback(spawn) -> None:
    router_port, peer_port = free_tcp_port(), free_tcp_port()
    proc = spawn.python(["-c", SESSIONS, str(router_port), str(peer_port)], stdin=subprocess.PIPE)
    assert wait_for_line(proc, 60.0) == "ready", proc.stderr.read().decode()
    sockets = process_sockets(proc.pid)
    assert off_loopback(sockets) == [], sockets
    listening = {s.local for s in sockets if s.proto.startswith("tcp") and s.state == TCP_LISTEN}
    loopback = ipaddress.ip_address("127.0.0.1")
    # The two explicit listeners plus peer_b's default ephemeral loopback listener.
    assert (loopback, router_port) in listening and (loopback, peer_port) in listening
    assert len(listening) >= 3
    established = [s for s in sockets if s.proto.startswith("tcp") and s.state == "01"]
    assert len(established) >= 4  # both ends of client-router and peer_b-peer_a
    assert not any(s.proto.startswith(("udp", "raw")) for s in sockets)
    proc.stdin.close()
    proc.wait(timeout=20.0)


def test_zenoh_socket_check_catches_non_loopback_sockets(spawn) -> None:
    # The check itself must be able to fail: a process with an all-interfaces UDP socket and
    # an all-interfaces TCP listener (neither sends anything) is flagged, its loopback
    # listener is not.
    proc = spawn.python(["-c", LEAKY], stdin=subprocess.PIPE)
    assert wait_for_line(proc, 20.0) == "ready"
    bad = off_loopback(process_sockets(proc.pid))
    assert sorted(s.proto for s in bad) == ["tcp", "udp"]
    assert all(s.local[0] == ipaddress.ip_address("0.0.0.0") for s in bad)
    proc.stdin.close()
    proc.wait(timeout=10.0)

"""The kernel's objects of a lab (docs/lab.md, "What up makes", "Impaired links"). Every
command names a namespace: nothing here creates or changes anything in the namespace it is run
from."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from hil.errors import BadInputError

NETNS_DIR = Path("/run/netns")
SUBNET = "10.231.0"  # /24, only inside the lab's namespaces
BRIDGE = "br0"
HOST_LINK = "eth0"
TABLE = "hillab_impair"
LOSS_SCALE = 1_000_000
RATE_MTU = 1500
RATE_LATENCY = "100ms"


class LabError(BadInputError):
    """A lab command that failed: one line naming the command and the kernel's answer."""


def run(argv: list[str], stdin: str | None = None) -> str:
    proc = subprocess.run(argv, input=stdin, capture_output=True, text=True)
    if proc.returncode != 0:
        why = " ".join(proc.stderr.split())[:300] or f"exit {proc.returncode}"
        raise LabError(f"lab: {' '.join(argv[:6])} failed: {why}")
    return proc.stdout


def netns_exists(name: str) -> bool:
    return (NETNS_DIR / name).exists()


def netns_path(name: str) -> str:
    return str(NETNS_DIR / name)


def add_netns(name: str) -> None:
    run(["ip", "netns", "add", name])
    run(["ip", "-n", name, "link", "set", "lo", "up"])


def kill_pids(pids: list[int], grace: float = 3.0) -> None:
    """SIGTERM, then SIGKILL after ``grace`` seconds, to each PID still there."""
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 1.0)):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline and any(Path(f"/proc/{p}").exists() for p in pids):
            time.sleep(0.02)
            for pid in pids:  # collect this process's children among them (else zombies stay)
                with contextlib.suppress(ChildProcessError, OSError):
                    os.waitpid(pid, os.WNOHANG)


def del_netns(name: str) -> None:
    """Stop every process left in the namespace (all of them the lab's: it made the
    namespace), then delete it (its links go with it)."""
    if not netns_exists(name):
        return
    proc = subprocess.run(["ip", "netns", "pids", name], capture_output=True, text=True)
    kill_pids([int(p) for p in proc.stdout.split() if p.isdigit()])
    run(["ip", "netns", "del", name])


def make_switch(ns: str) -> None:
    run(["ip", "-n", ns, "link", "add", BRIDGE, "type", "bridge"])
    run(["ip", "-n", ns, "link", "set", BRIDGE, "up"])


def host_address(index: int) -> str:
    return f"{SUBNET}.{index}"


def link_host(switch_ns: str, host_ns: str, index: int) -> None:
    """A veth pair: ``eth0`` in the host with its address, ``vh<index>`` on the bridge."""
    port = f"vh{index}"
    peer = ["peer", "name", HOST_LINK, "netns", host_ns]
    run(["ip", "-n", switch_ns, "link", "add", port, "type", "veth", *peer])
    run(["ip", "-n", switch_ns, "link", "set", port, "master", BRIDGE, "up"])
    run(["ip", "-n", host_ns, "addr", "add", f"{host_address(index)}/24", "dev", HOST_LINK])
    run(["ip", "-n", host_ns, "link", "set", HOST_LINK, "up"])


@dataclass(frozen=True)
class LinkImpairment:
    """A host link's impairment: ``loss`` fraction of the packets the host receives dropped
    at random, ``rate_bps`` cap on what it sends (0: none)."""

    loss: float = 0.0
    rate_bps: float = 0.0

    def ruleset(self) -> str:
        k = round(self.loss * LOSS_SCALE)
        return f"""table inet {TABLE} {{
  chain input {{
    type filter hook input priority 0; policy accept;
    iifname "{HOST_LINK}" counter comment "received"
    iifname "{HOST_LINK}" numgen random mod {LOSS_SCALE} < {k} counter drop comment "dropped"
  }}
}}
"""


def impair(host_ns: str, imp: LinkImpairment) -> None:
    if imp.loss > 0:
        run(["nsenter", f"--net={netns_path(host_ns)}", "nft", "-f", "-"], stdin=imp.ruleset())
    if imp.rate_bps > 0:
        burst = max(2 * (RATE_MTU + 14), round(imp.rate_bps / 8 * 0.004))
        run(["ip", "-n", host_ns, "link", "set", HOST_LINK, "mtu", str(RATE_MTU)])
        tbf = ["rate", f"{round(imp.rate_bps)}bit", "burst", str(burst), "latency", RATE_LATENCY]
        run(["tc", "-n", host_ns, "qdisc", "add", "dev", HOST_LINK, "root", "tbf", *tbf])


def impair_counters(host_ns: str) -> dict[str, int]:
    """Packets received on the host's link and dropped there ({} without a loss rule)."""
    argv = ["nsenter", f"--net={netns_path(host_ns)}", "nft", "-j", "list", "table", "inet", TABLE]
    proc = subprocess.run(argv, capture_output=True, text=True)
    if proc.returncode != 0:
        return {}
    out: dict[str, int] = {}
    for item in json.loads(proc.stdout).get("nftables", []):
        rule = item.get("rule") or {}
        for expr in rule.get("expr", []):
            if "counter" in expr and rule.get("comment"):
                out[rule["comment"]] = int(expr["counter"]["packets"])
    return out

"""``hil lab up`` / ``down`` / ``status``: build, remove and show a lab (docs/lab.md)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import NotRequired, TypedDict

from hil import interrupts
from hil.bench.lab import net
from hil.bench.lab.state import (
    MARK_ENV,
    PREFIX,
    LabHost,
    LabState,
    Made,
    lab_dir,
    load,
    names,
    proc_start,
)

NAME_RE = re.compile(r"[a-z0-9]{1,12}")
HOSTS_MAX = 32
# Host i's CLOCK_MONOTONIC offset unless given: different signs and sizes, so that a figure
# that forgot to relate two clocks is wrong by seconds, not by a rounding.
DEFAULT_OFFSETS = (3.2, -1.7, 0.9, -4.45, 6.15, -2.35, 1.55, -5.05)
ROUTER_PORT = 7447
ROUTER_READY_S = 30.0


def default_offset(index: int) -> float:
    n = len(DEFAULT_OFFSETS)
    return DEFAULT_OFFSETS[(index - 1) % n] + 10.0 * ((index - 1) // n)


def host_name(index: int) -> str:
    return f"h{index}"


def netns_name(lab: str, host: str) -> str:
    return f"{PREFIX}{lab}-{host}"


def router_endpoint(index: int) -> str:
    return f"tcp/{net.host_address(index)}:{ROUTER_PORT}"


LOCAL_ROUTER = f"tcp/127.0.0.1:{ROUTER_PORT}"  # a host's own router, from the host


def check_name(name: str) -> str:
    if not NAME_RE.fullmatch(name):
        raise net.LabError(f"--name {name!r}: 1-12 characters of [a-z0-9]")
    return name


def require_root(what: str = "hil lab") -> None:
    if os.geteuid() != 0:
        raise net.LabError(
            f"{what} needs root: it makes network and time namespaces, veth links, nftables "
            "rules and tc qdiscs (run it as root, e.g. with sudo)"
        )
    for tool, package in (("ip", "iproute2"), ("nsenter", "util-linux"), ("mount", "mount")):
        if shutil.which(tool) is None:
            raise net.LabError(f"{what} needs {tool} (Debian package {package}): not found")


def host_of(state: LabState, host: str) -> LabHost:
    for h in state.hosts:
        if h["name"] == host:
            return h
    known = ", ".join(h["name"] for h in state.hosts) or "none"
    raise net.LabError(f"lab {state.name} has no host {host!r} (hosts: {known})")


def host_command(state: LabState, host: str, argv: list[str]) -> list[str]:
    """``argv`` run in the host's network and time namespaces."""
    h = host_of(state, host)
    return ["nsenter", f"--net={net.netns_path(h['netns'])}", f"--time={h['timens']}", "--", *argv]


def host_env(state: LabState, base: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of a process the lab starts: its owner mark added."""
    return {**(os.environ if base is None else base), MARK_ENV: state.mark}


def _make_host(state: LabState, index: int, offset: float, imp: net.LinkImpairment) -> None:
    name = host_name(index)
    ns = state.intend(Made("netns", netns_name(state.name, name))).name
    net.add_netns(ns)
    net.link_host(netns_name(state.name, "sw"), ns, index)
    tfile = lab_dir(state.name) / f"{name}.time"
    tfile.touch()
    state.intend(Made("timens", str(tfile)))
    net.run([sys.executable, "-m", "hil.bench.lab.timens", str(tfile), repr(offset)])
    net.impair(ns, imp)  # nothing without loss or rate
    host = LabHost(
        name=name,
        netns=ns,
        timens=str(tfile),
        address=net.host_address(index),
        offset_s=offset,
        router=router_endpoint(index),
        impair=asdict(imp),
    )
    state.hosts.append(host)
    state.save()


def _start_router(state: LabState, index: int) -> None:
    name = host_name(index)
    item = state.intend(Made("proc", f"router-{name}"))
    argv = [sys.executable, "-m", "hil.bench.lab.router", "--listen", LOCAL_ROUTER]
    argv += ["--listen", router_endpoint(index)]
    argv += [arg for j in range(1, index) for arg in ("--connect", router_endpoint(j))]
    log_path = lab_dir(state.name) / f"{name}.router.log"
    with log_path.open("wb") as log:
        proc = subprocess.Popen(
            host_command(state, name, argv),
            env=host_env(state),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # the lab outlives the command that built it
        )
    item.pid, item.start = proc.pid, proc_start(proc.pid) or 0
    state.save()
    host_of(state, name)["router_pid"] = proc.pid
    deadline = time.monotonic() + ROUTER_READY_S
    while b"router up" not in log_path.read_bytes():
        if proc.poll() is not None or time.monotonic() > deadline:
            tail = log_path.read_text(errors="replace").strip().splitlines()[-1:]
            raise net.LabError(f"lab: the router of {name} did not start: {tail}")
        time.sleep(0.05)


def up(
    name: str,
    hosts: int,
    offsets: dict[str, float] | None = None,
    impairments: dict[str, net.LinkImpairment] | None = None,
) -> LabState:
    """Build the lab; on any failure or interrupt remove what was made and raise."""
    require_root("hil lab up")
    check_name(name)
    if not 1 <= hosts <= HOSTS_MAX:
        raise net.LabError(f"--hosts {hosts}: 1 to {HOSTS_MAX}")
    offsets, impairments = offsets or {}, impairments or {}
    hostnames = [host_name(i) for i in range(1, hosts + 1)]
    for host in {**offsets, **impairments}:
        if host not in hostnames:
            raise net.LabError(f"lab: no host {host!r} among h1..h{hosts}")
    if any(i.loss > 0 for i in impairments.values()) and shutil.which("nft") is None:
        raise net.LabError("a link's loss needs nft (Debian package nftables): not found")
    clean_leftovers(name)
    for ns in [netns_name(name, host) for host in ("sw", *hostnames)]:
        if net.netns_exists(ns):
            raise net.LabError(f"lab: a network namespace {ns} exists that is not this lab's")
    state = LabState(name, owner_start=proc_start(os.getpid()) or 0)
    state.save()
    try:
        switch = state.intend(Made("netns", netns_name(name, "sw"))).name
        net.add_netns(switch)
        net.make_switch(switch)
        for i, host in enumerate(hostnames, start=1):
            imp = impairments.get(host, net.LinkImpairment())
            _make_host(state, i, offsets.get(host, default_offset(i)), imp)
        for i in range(1, hosts + 1):
            _start_router(state, i)
    except BaseException:
        with interrupts.shielded():
            teardown(state)
        raise
    state.phase = "up"
    state.save()
    return state


def clean_leftovers(name: str) -> bool:
    """Remove what a lab of that name left behind (its builder killed, or not taken down);
    refuse while another command is building it. True when something was removed."""
    state = load(name)
    if state is None:
        return False
    if state.phase == "building" and state.owner_alive():
        raise net.LabError(f"lab {name} is being built by PID {state.owner_pid}")
    procs = [m for m in state.made if m.kind == "proc"]
    if state.phase == "up" and procs and all(state.owns_process(m) for m in procs):
        raise net.LabError(f"lab {name} is up (hil lab down --name {name} first)")
    teardown(state)
    return True


def _mounted(path: str) -> bool:
    with open("/proc/self/mountinfo") as f:
        return any(line.split()[4] == path for line in f)


def teardown(state: LabState) -> list[str]:
    """Remove every object the state lists, newest first, and the lab's folder; what could
    not be removed (one line each). Only what the state proves is the lab's is touched."""
    problems: list[str] = []
    own_prefix = f"{PREFIX}{state.name}-"
    folder = lab_dir(state.name)
    net.kill_pids([m.pid for m in state.made if m.kind == "proc" and state.owns_process(m)])
    for item in reversed(state.made):
        try:
            if item.kind == "netns" and item.name.startswith(own_prefix):
                net.del_netns(item.name)
            elif item.kind == "timens" and Path(item.name).parent == folder:
                while _mounted(item.name):
                    net.run(["umount", item.name])
        except net.LabError as exc:
            problems.append(str(exc))
    if not problems:
        shutil.rmtree(folder, ignore_errors=True)
    return problems


class LabDown(TypedDict):
    """What ``hil lab down`` prints (one JSON line)."""

    lab: str
    removed: bool
    note: NotRequired[str]  # why nothing was removed
    objects: NotRequired[int]  # how many namespaces and processes were removed


class HostStatus(TypedDict):
    """One host in ``hil lab status``: its state file's facts and what is there now."""

    name: str
    address: str
    offset_s: float
    router: str
    impair: dict[str, float]
    netns: str | None  # None: its network namespace is gone
    router_running: bool
    counters: NotRequired[dict[str, int]]  # an impaired link's loss counters


class LabStatus(TypedDict):
    """One lab in ``hil lab status``."""

    lab: str
    phase: str  # building, up, or leftover (built by a process that died)
    hosts: list[HostStatus]


def down(name: str) -> LabDown:
    require_root("hil lab down")
    check_name(name)
    state = load(name)
    if state is None:
        return {"lab": name, "removed": False, "note": "no such lab"}
    if state.phase == "building" and state.owner_alive():
        raise net.LabError(f"lab {name} is being built by PID {state.owner_pid}")
    with interrupts.shielded():
        problems = teardown(state)
    if problems:
        raise net.LabError("; ".join(problems))
    return {"lab": name, "removed": True, "objects": len(state.made)}


def status(name: str | None = None) -> list[LabStatus]:
    """Each lab (or the named one): phase, hosts, whether each namespace and router is there,
    the loss counters of impaired links."""
    out: list[LabStatus] = []
    for lab in [name] if name else names():
        state = load(lab)
        if state is None:
            continue
        owned = {m.name: state.owns_process(m) for m in state.made if m.kind == "proc"}
        hosts: list[HostStatus] = []
        for h in state.hosts:
            row: HostStatus = {
                "name": h["name"],
                "address": h["address"],
                "offset_s": h["offset_s"],
                "router": h["router"],
                "impair": h["impair"],
                "netns": h["netns"] if net.netns_exists(h["netns"]) else None,
                "router_running": owned.get(f"router-{h['name']}", False),
            }
            if h["impair"]["loss"] > 0 and row["netns"]:
                row["counters"] = net.impair_counters(h["netns"])
            hosts.append(row)
        leftover = state.phase == "building" and not state.owner_alive()
        out.append({"lab": lab, "phase": "leftover" if leftover else state.phase, "hosts": hosts})
    return out

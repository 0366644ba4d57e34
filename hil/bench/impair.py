"""``[impair]``: packets of a run's real links dropped and counted by the kernel, in the run's
own network namespace (docs/impair.md: which packets ``on`` selects, how, and why at the input
hook).

``hil run`` with an ``[impair]`` table re-executes itself under ``unshare --net`` (unshare execs,
so the PID stays) with :data:`NETNS_ENV` set to that PID; there :func:`enter` installs the
rules, and :func:`finish` reads the kernel's counters into summary.json ``impair``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack

import hil
from hil.bench.settings import effective_can_table
from hil.bundled import resolve_scenario
from hil.errors import BadInputError
from hil.folder import layout
from hil.folder.records import ImpairFacts, RateLimit, RunExtra
from hil.scenario import Scenario, load_scenario
from protocol.can.codec import Cmd, frame_id

NETNS_ENV = "HIL_IMPAIR_NETNS"  # the PID of the ``hil run`` that made this namespace
TABLE = "hil_impair"
# python-can's udp_multicast sends every frame to this UDP port (UdpMulticastBus(port=43113);
# the run's [can] table has no port key, so it is always the default).
UDP_MULTICAST_PORT = 43113
# ``loss`` is applied as ``numgen random mod LOSS_SCALE < round(loss * LOSS_SCALE)``.
LOSS_SCALE = 1_000_000
# udp_multicast's packet is python-can's ``pack_message``: a msgpack map whose keys come in a
# fixed order, ``timestamp`` first (a float64: 0x8b, 0xa9 "timestamp", 0xcb + 8 bytes), so the
# key ``arbitration_id`` (0xae + 14 bytes) always starts 20 bytes into the UDP payload, and its
# value follows it as a msgpack unsigned integer. Matching the key too makes the match exact: a
# packet laid out otherwise is never taken for a torque frame.
ARBITRATION_KEY = b"\xaearbitration_id"
ARBITRATION_KEY_OFFSET = 20  # bytes into the UDP payload
UDP_HEADER = 8  # bytes: nftables' ``@th`` offsets count from the UDP header
# tc's token bucket on the loopback: the link's MTU becomes Ethernet's (the loopback's 64 KiB
# packets would not fit a small bucket), the bucket holds two frames or 4 ms of traffic, and a
# packet that would wait longer than the queue's latency is dropped.
RATE_MTU = 1500
RATE_LATENCY = "100ms"


@dataclass(frozen=True)
class Plan:
    """What one run impairs: the scenario's table, the nftables selectors and their meaning."""

    config: Any  # hil.scenario.ImpairConfig
    selectors: tuple[str, ...]
    packets: str  # one line: which packets the selectors take
    warning: str = ""


def msgpack_uint(value: int) -> bytes:
    """``value`` as msgpack (python-can's ``pack_message``) writes a non-negative integer."""
    return bytes(msgpack.packb(value))


def torque_selector(node: int) -> str:
    """The nftables match of one drive's Set_Input_Torque frames on udp_multicast."""
    value = msgpack_uint(frame_id(node, Cmd.SET_INPUT_TORQUE))
    key_bits = (UDP_HEADER + ARBITRATION_KEY_OFFSET) * 8
    value_bits = key_bits + len(ARBITRATION_KEY) * 8
    return (
        f"udp dport {UDP_MULTICAST_PORT} "
        f"@th,{key_bits},{len(ARBITRATION_KEY) * 8} 0x{ARBITRATION_KEY.hex()} "
        f"@th,{value_bits},{len(value) * 8} 0x{value.hex()}"
    )


def _can_selectors(config: Any, interface: str | None, nodes: tuple[int, int]) -> list[str]:
    """The CAN bus's packets: udp_multicast's, one frame each; [] for a bus without packets
    of its own (refused where ``on = 'can'`` asks for it)."""
    if interface == "udp_multicast":
        if config.can_frames == "torque":
            return [torque_selector(n) for n in nodes]
        return [f"udp dport {UDP_MULTICAST_PORT}"]
    if config.on != "can":
        return []
    if interface is None:
        raise BadInputError("[impair] on = 'can': this run opens no CAN bus")
    raise BadInputError(
        f"[impair] on = 'can' needs the CAN interface 'udp_multicast' (a frame per packet), "
        f"the run's is {interface!r}: zenoh_can's frames ride on the Zenoh links (on = "
        "'zenoh'), a kernel CAN bus carries no packets"
    )


def selectors(config: Any, interface: str | None, nodes: tuple[int, int]) -> Plan:
    """The selectors of ``config`` for a run whose CAN bus is ``interface`` (None: no bus);
    a table the run cannot honour raises BadInputError naming the key."""
    picked: list[str] = []
    what: list[str] = []
    warning = ""
    if config.on in ("can", "all"):
        picked += _can_selectors(config, interface, nodes)
        if config.can_frames == "torque":
            what.append(f"Set_Input_Torque frames of CAN nodes {nodes[0]}, {nodes[1]}")
        elif picked:
            what.append(f"every CAN frame (UDP to port {UDP_MULTICAST_PORT})")
        elif interface not in (None, "zenoh_can"):
            warning = f"[impair] on = 'all': the {interface} bus carries no packets, not impaired"
    if config.on in ("zenoh", "all"):
        picked.append("meta l4proto tcp")
        carried = ", with zenoh_can's CAN frames" if interface == "zenoh_can" else ""
        what.append(f"every TCP packet (the Zenoh links{carried})")
    return Plan(config, tuple(picked), "; ".join(what), warning)


def ruleset(plan: Plan) -> str:
    """The nftables table: the selected packets jump to a chain that counts them all and drops
    every ``loss_every``-th (``numgen inc``: the n-th, 2n-th, ... selected packet) or a
    ``loss`` fraction at random."""
    cfg = plan.config
    lossy = ['    counter comment "matched"']
    if cfg.loss_every > 0:
        n = cfg.loss_every
        lossy.append(f'    numgen inc mod {n} == {n - 1} counter drop comment "dropped"')
    elif cfg.loss > 0:
        k = round(cfg.loss * LOSS_SCALE)
        lossy.append(f'    numgen random mod {LOSS_SCALE} < {k} counter drop comment "dropped"')
    lines = [f"table inet {TABLE} {{", "  chain lossy {", *lossy, "  }", "  chain input {"]
    lines.append("    type filter hook input priority 0; policy accept;")
    lines += [f"    {s} jump lossy" for s in plan.selectors]
    return "\n".join([*lines, "  }", "}", ""])


def plan_of(
    opts: Any, check_options: Callable[[Any], None], load: Callable[[], Scenario] | None = None
) -> Plan | None:
    """The run's plan, or None when its scenario has no [impair] table; ``check_options``
    (hil run's) first, so a bad option is reported as it always is; ``load``: the scenario
    file's parse, shared with the run."""
    if opts.scenario is None:
        return None
    check_options(opts)
    scenario = load() if load is not None else load_scenario(resolve_scenario(opts.scenario))
    if scenario.impair is None:
        return None
    can = effective_can_table(scenario, opts.can_interface)
    bus = opts.can_live or opts.cmd_path == "can"
    nodes = (int(can["node_left"]), int(can["node_right"]))
    return selectors(scenario.impair, can["interface"] if bus else None, nodes)


def started_as_hil_run() -> bool:
    """True when this process is ``hil run`` from its own command line (``hil run ...`` or
    ``python -m hil run ...``): only then can it be executed again as it was started."""
    argv0 = Path(sys.argv[0])
    own = argv0.name == "hil" or argv0.resolve() == Path(hil.__file__).parent / "__main__.py"
    return own and len(sys.argv) > 1 and sys.argv[1] == "run"


def _check_can_isolate(plan: Plan) -> str:
    """``unshare``'s path once root, the tools and a namespace work; else a BadInputError why."""
    if os.geteuid() != 0:
        raise BadInputError(
            "[impair] needs root: hil run makes the run's own network namespace (unshare "
            "--net) and sets nftables rules there"
        )
    tools = {"unshare": "util-linux", "ip": "iproute2", "nft": "nftables"}
    if plan.config.rate_bps > 0:
        tools["tc"] = "iproute2"
    for tool, package in tools.items():
        if shutil.which(tool) is None:
            raise BadInputError(f"[impair] needs {tool} (Debian package {package}): not found")
    unshare = str(shutil.which("unshare"))
    probe = subprocess.run([unshare, "--net", "true"], capture_output=True, text=True)
    if probe.returncode != 0:
        why = (probe.stderr.strip().splitlines() or [f"exit {probe.returncode}"])[-1]
        raise BadInputError(f"[impair] cannot make a network namespace: {why}")
    return unshare


def _run(argv: list[str], stdin: str | None = None) -> str:
    """A namespace command's stdout; its failure as a BadInputError (one line)."""
    proc = subprocess.run(argv, input=stdin, capture_output=True, text=True)
    if proc.returncode != 0:
        why = " ".join(proc.stderr.split())[:300] or f"exit {proc.returncode}"
        raise BadInputError(f"[impair] {' '.join(argv[:4])} failed: {why}")
    return proc.stdout


def _install(plan: Plan) -> None:
    """Loopback up with multicast and its route, the rules, the rate limit."""
    _run(["ip", "link", "set", "lo", "up"])
    _run(["ip", "link", "set", "lo", "multicast", "on"])
    _run(["ip", "route", "add", "224.0.0.0/4", "dev", "lo"])
    _run(["nft", "-f", "-"], stdin=ruleset(plan))
    rate = plan.config.rate_bps
    if rate > 0:
        burst = max(2 * (RATE_MTU + 14), round(rate / 8 * 0.004))
        _run(["ip", "link", "set", "lo", "mtu", str(RATE_MTU)])
        tbf = ["rate", f"{round(rate)}bit", "burst", str(burst), "latency", RATE_LATENCY]
        _run(["tc", "qdisc", "add", "dev", "lo", "root", "tbf", *tbf])


def enter(
    opts: Any, check_options: Callable[[Any], None], load: Callable[[], Scenario] | None = None
) -> Plan | None:
    """Before ``hil run`` prepares anything: None without [impair]; else, the first time,
    re-execute this command in a fresh network namespace (never returns), and inside it install
    the impairment and return its plan. BadInputError (exit 2) when that cannot be done."""
    plan = plan_of(opts, check_options, load)
    if plan is None:
        return None
    # Not yet in the namespace this very hil run made (a child inherits the variable, not the PID).
    if os.environ.get(NETNS_ENV) != str(os.getpid()):
        if not started_as_hil_run():
            raise BadInputError(
                "[impair] runs in hil run's own network namespace: start it as `hil run` "
                "(or python -m hil run), which re-executes itself under unshare --net"
            )
        unshare = _check_can_isolate(plan)
        sys.stdout.flush()
        sys.stderr.flush()
        env = {**os.environ, NETNS_ENV: str(os.getpid())}
        os.execve(unshare, [unshare, "--net", "--", sys.executable, *sys.orig_argv[1:]], env)
    if plan.warning:
        print(f"warning: {plan.warning}", file=sys.stderr)
    _install(plan)
    return plan


def _nft_counters() -> dict[str, int]:
    """Packets counted by the rules named ``matched`` and ``dropped``."""
    data = json.loads(_run(["nft", "-j", "list", "table", "inet", TABLE]))
    rules = [item["rule"] for item in data.get("nftables", []) if item.get("rule")]
    return {
        rule["comment"]: int(expr["counter"]["packets"])
        for rule in rules
        if rule.get("comment") in ("matched", "dropped")
        for expr in rule.get("expr", [])
        if "counter" in expr
    }


def _tc_counters() -> RateLimit:
    """The loopback's token bucket: packets sent, dropped, held over the limit."""
    data = json.loads(_run(["tc", "-s", "-j", "qdisc", "show", "dev", "lo"]))
    tbf = next((q for q in data if q.get("kind") == "tbf"), {})
    return {
        "packets": tbf.get("packets"),
        "dropped_packets": tbf.get("drops"),
        "overlimits": tbf.get("overlimits"),
        "burst_bytes": (tbf.get("options") or {}).get("burst"),
        "latency": RATE_LATENCY,
        "mtu": RATE_MTU,
    }


def finish(plan: Plan | None, run_dir: Path) -> RunExtra:
    """summary.json's ``impair`` (the kernel's counters) and ``impair.nft``; {} without [impair]."""
    if plan is None:
        return {}
    (run_dir / layout.IMPAIR_RULES).write_text(ruleset(plan))
    facts: ImpairFacts = {
        "config": dataclasses.asdict(plan.config),
        "namespace": "private (unshare --net), loopback only",
        "packets": plan.packets,
        "rules": layout.IMPAIR_RULES,
        "matched_packets": None,
        "dropped_packets": None,
        "rate_limit": None,
    }
    try:
        counts = _nft_counters()
        facts["matched_packets"] = counts.get("matched", 0)
        facts["dropped_packets"] = counts.get("dropped", 0)
        if plan.config.rate_bps > 0:
            facts["rate_limit"] = {"rate_bps": plan.config.rate_bps, **_tc_counters()}
    except (BadInputError, ValueError) as exc:
        facts["error"] = f"counters not read: {exc}"
    return {"impair": facts}

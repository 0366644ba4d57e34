"""Loss on a real wire: ``[impair]`` drops packets of a run's real links with nftables, in
``hil run``'s own network namespace (hil/bench/impair.py, docs/impair.md).

On the CAN path over python-can's ``udp_multicast`` only the drives' Set_Input_Torque frames are
dropped, every N-th on the wire. Their wire order is the controller's ``can_tx`` order, so which
frames were dropped is known exactly (bench/wire_loss.py ``expected_losses``, cross-checked here
against nftables' own counters and the plant's received frames): the bench must count exactly
those as lost, match every other frame to its send (no value mismatch) and keep the hop at its
true size. On the Zenoh path (TCP on the namespace's loopback) a fraction of packets is dropped
at random: TCP's retransmissions delay commands, and the certificate must name those stalls
with a cause. Processes are stopped by PID (the ``spawn`` fixture); no packet leaves the host.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import can
import pytest
from can.interfaces.udp_multicast.utils import pack_message

from bench.wire_loss import expected_losses, hil_run_args, scenario_text
from hil.analysis.measure.stalls import TABLE
from hil.bench import impair
from hil.errors import BadInputError
from hil.scenario import ImpairConfig
from protocol.can.codec import Heartbeat, SetInputTorque, frame_id
from protocol.can.codec import encode as can_encode
from protocol.can.drive_link import to_message
from tests.run_helpers import Expect, check_verdict, fails

ROOT = Path(__file__).resolve().parents[1]
EVERY = 49  # odd: the two drives' frames alternate on the wire, so both lose frames
# The causes a stall made by a lossy transport may carry: the transport's, or the controller's
# when it was itself held up while the link recovered (a 0.44 s controller lateness was seen at
# 5 % loss).
TRANSPORT_CAUSES = {
    "command_lost",
    "state_lost",
    "transport_late",
    "command_delayed",
    "controller_late",
}


def _netns_unavailable() -> str | None:
    """Why this host cannot run an impaired run (None: it can)."""
    if os.geteuid() != 0:
        return "needs root: hil run makes a network namespace and sets nftables rules in it"
    for tool, package in (("unshare", "util-linux"), ("ip", "iproute2"), ("nft", "nftables")):
        if shutil.which(tool) is None:
            return f"{tool} not installed (Debian package {package}; .ci/run installs it)"
    probe = subprocess.run(["unshare", "--net", "true"], capture_output=True, text=True)
    if probe.returncode != 0:
        return f"cannot make a network namespace here: {probe.stderr.strip()}"
    return None


needs_netns = pytest.mark.skipif(_netns_unavailable() is not None, reason=str(_netns_unavailable()))


# --- the match and the plan, in process ---------------------------------------------------


@pytest.mark.parametrize("node", [0, 1, 3, 4, 63])
def test_the_torque_match_is_where_python_can_packs_the_arbitration_id(node: int) -> None:
    """The nftables payload offsets against python-can's own packing of the controller's
    frame (as protocol.can.drive_link sends it): key and id at the offsets the rule reads,
    and another command of the same drive differs there."""
    payload = pack_message(to_message(can_encode(SetInputTorque(node, 0.25))))
    key_at = impair.ARBITRATION_KEY_OFFSET
    key = impair.ARBITRATION_KEY
    value = impair.msgpack_uint(frame_id(node, 0x0E))
    assert payload[key_at : key_at + len(key)] == key
    assert payload[key_at + len(key) : key_at + len(key) + len(value)] == value
    rule = impair.torque_selector(node)
    bits = (impair.UDP_HEADER + key_at) * 8
    assert f"@th,{bits},{len(key) * 8} 0x{key.hex()}" in rule
    assert f"@th,{bits + len(key) * 8},{len(value) * 8} 0x{value.hex()}" in rule
    other = pack_message(to_message(can_encode(Heartbeat(node, 0, 8))))
    assert other[key_at + len(key) : key_at + len(key) + len(value)] != value
    extended = pack_message(can.Message(arbitration_id=0x0E, is_extended_id=True, data=b""))
    assert len(extended) > key_at + len(key)  # the layout does not depend on the frame's kind
    assert extended[key_at : key_at + len(key)] == key


def test_a_plan_names_what_it_drops_or_refuses_what_the_run_cannot_impair() -> None:
    torque = impair.selectors(ImpairConfig(on="can", can_frames="torque"), "udp_multicast", (0, 1))
    assert len(torque.selectors) == 2 and "Set_Input_Torque" in torque.packets
    every = impair.selectors(ImpairConfig(loss_every=97), "udp_multicast", (0, 1))
    assert every.selectors == ("udp dport 43113", "meta l4proto tcp")
    assert "numgen inc mod 97 == 96 counter drop" in impair.ruleset(every)
    zenoh = impair.selectors(ImpairConfig(on="zenoh", loss=0.02), "zenoh_can", (0, 1))
    assert zenoh.selectors == ("meta l4proto tcp",) and "zenoh_can" in zenoh.packets
    assert "numgen random mod 1000000 < 20000 counter drop" in impair.ruleset(zenoh)
    assert "drop" not in impair.ruleset(impair.selectors(ImpairConfig(), None, (0, 1)))
    kernel_bus = impair.selectors(ImpairConfig(loss=0.1), "socketcan", (0, 1))
    assert kernel_bus.selectors == ("meta l4proto tcp",) and "socketcan" in kernel_bus.warning
    for interface in ("zenoh_can", "socketcan", None):
        with pytest.raises(BadInputError, match=r"^\[impair\] on = 'can'"):
            impair.selectors(ImpairConfig(on="can", loss=0.1), interface, (0, 1))


def test_an_impaired_run_is_refused_outside_the_hil_command(tmp_path: Path) -> None:
    """execute() called in process cannot move its caller into a namespace: a clear error,
    nothing written."""
    from hil.bench.lifecycle import execute
    from hil.bench.prepare import RunOptions

    scenario = tmp_path / "s.toml"
    scenario.write_text(scenario_text(EVERY, torque_only=False))
    out = tmp_path / "run"
    with pytest.raises(BadInputError, match=r"^\[impair\] runs in hil run's own network"):
        execute(
            RunOptions(scenario=scenario, out=out, cmd_path="can", can_interface="udp_multicast")
        )
    assert not out.exists()


def test_an_impaired_run_needs_root(monkeypatch: pytest.MonkeyPatch) -> None:
    plan = impair.selectors(ImpairConfig(on="can", loss_every=9), "udp_multicast", (0, 1))
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    with pytest.raises(BadInputError, match=r"^\[impair\] needs root: hil run makes"):
        impair._check_can_isolate(plan)


@pytest.mark.skipif(os.geteuid() != 0, reason="root only: without root the run stops earlier")
def test_an_impaired_run_without_nft_exits_2_with_one_line(tmp_path: Path) -> None:
    (tmp_path / "s.toml").write_text(scenario_text(EVERY, torque_only=True))
    tools = tmp_path / "bin"  # unshare and ip, but no nft
    tools.mkdir()
    for tool in ("unshare", "ip"):
        (tools / tool).symlink_to(str(shutil.which(tool)))
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "run", str(tmp_path / "s.toml"), "--cmd-path", "can",
         "--can-interface", "udp_multicast", "--out", str(tmp_path / "run")],
        cwd=ROOT, env={**os.environ, "PATH": str(tools)}, capture_output=True, text=True,
        timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == "error: [impair] needs nft (Debian package nftables): not found\n"
    assert not (tmp_path / "run").exists()


# --- real runs ------------------------------------------------------------------------------


#: At 500 Hz a loaded host may add these to what the loss causes (tests/run_helpers.py
#: LOADED_HOST), each explained by the run's own logs; nothing else.
LOAD = ("deadline_misses", "bench_stalled")


def _hil_run(spawn, args: list[str], expect: Expect) -> tuple[int, dict, str]:
    """``python -m hil ARGS`` (stopped by PID whatever happens); exit code, summary, stderr.
    Its verdict is ``expect``, with that verdict's exit code."""
    proc = spawn.python(["-m", "hil", *args], cwd=ROOT, text=True)
    _, err = proc.communicate(timeout=240)
    out = Path(args[args.index("--out") + 1])
    assert (out / "summary.json").is_file(), (proc.returncode, err[-3000:])
    summary = json.loads((out / "summary.json").read_text())
    check_verdict(summary, expect, proc.returncode, out, context=err[-3000:])
    return proc.returncode, summary, err


@pytest.mark.realtime
@needs_netns
def test_a_torque_frame_dropped_on_the_wire_is_one_lost_frame(spawn, tmp_path: Path) -> None:
    scenario = tmp_path / "s.toml"
    scenario.write_text(scenario_text(EVERY, torque_only=True))
    out = tmp_path / "run"
    # Every 49th torque frame dropped: its command lost (2 % of the messages) and its sample
    # without a command; D stays a few periods (a lost command widens the gap by one).
    expect = fails("lost_messages", "samples_without_command", also=LOAD)
    code, s, err = _hil_run(spawn, hil_run_args(scenario, out, duration=5.0, rate=500.0), expect)
    can_, kernel = s["messages"]["torque_can"], s["impair"]
    exp = expected_losses(out, EVERY)
    hop = s["timing"]["hop_cmd_can"]
    print(json.dumps({"exit": code, "impair": kernel, "torque_can": can_, "expected": exp}))
    print("hop_cmd_can", hop, "D", s["certificate"]["d_max_s"], err.strip()[-300:])
    assert s["error"] is None and not s["interrupted"]
    # The wire did what the rule says: nftables saw the controller's torque frames, one packet
    # each, dropped the EVERY-th ones, and the plant received every other frame, in order.
    assert kernel["matched_packets"] == exp["torque_frames_on_the_wire"] > 4 * 500
    assert kernel["dropped_packets"] == exp["dropped_torque_frames"] > 0
    assert exp["plant_received_the_survivors"] and exp["window_covers_every_command"]
    # The bench counts exactly those of the window's frames, and nothing shifts.
    assert can_["frames_lost"] <= kernel["dropped_packets"]
    assert can_["frames_lost"] == exp["frames_lost"] > 0
    assert can_["lost"] == exp["commands_lost"]
    assert can_["value_mismatches"] == 0
    # The hop covers every frame sent up to the last sample; the counts stop 2 Ts earlier
    # (while the drives still listen): at most the last 3 commands' frames apart.
    assert 0 <= hop["count"] - can_["frames_received"] <= 2 * 3, (hop, can_)
    assert "not_relatable" not in hop or hop["not_relatable"] <= can_["frames_ambiguous"]
    assert hop["p50_us"] < 2000, hop  # the true hop is a fraction of a millisecond


@pytest.mark.realtime
@needs_netns
def test_tcp_loss_under_zenoh_shows_as_stalls_with_a_cause(spawn, tmp_path: Path) -> None:
    scenario = tmp_path / "s.toml"
    scenario.write_text(
        scenario_text(EVERY, torque_only=False).replace(
            'on = "can"\ncan_frames = "all"\nloss_every = 49\n', 'on = "zenoh"\nloss = 0.05\n'
        )
    )
    out = tmp_path / "run"
    args = ["run", str(scenario), "--duration", "5", "--rate", "500", "--quiet", "--no-report"]
    # TCP resends what was dropped, late: D > D* by the transport (the system's), and the
    # States and commands that come in a burst after a resend leave samples without a command.
    expect = fails("certificate_system", "samples_without_command", also=LOAD)
    code, s, err = _hil_run(spawn, [*args, "--out", str(out)], expect)
    kernel, cert = s["impair"], s["certificate"]
    stalls = cert["stalls"]
    verdict = [line for line in err.splitlines() if line.startswith("verdict:")]
    print(json.dumps({"exit": code, "impair": kernel, "d_max_s": cert["d_max_s"]}))
    for stall in stalls:
        print("stall", stall)
    print(verdict)
    assert s["error"] is None and not s["interrupted"] and s["cmd_path"] == "zenoh"
    assert kernel["packets"].startswith("every TCP packet")
    assert 0.03 < kernel["dropped_packets"] / kernel["matched_packets"] < 0.07, kernel
    # TCP recovers a lost segment late (its timers are milliseconds to 200 ms): commands land
    # late, D passes D*, and the stalls say why.
    assert stalls, cert
    assert cert["held"] is False and cert["d_max_s"] > cert["d_star_s"], cert
    # Every stall that decides the verdict has a cause; the worst, a retransmission's, one of
    # the transport's (a host's own hiccup elsewhere in the run may be named as such).
    decisive = [st for st in stalls if st["age_s"] > cert["d_star_s"]]
    assert decisive and all(st["cause"] != "unknown" for st in decisive), decisive
    # The stretch before the first landing is named startup, its cause the row that decided it:
    # a loss that held the first command is the transport's there too (seen: 383 ms, row 13).
    worst = stalls[0]
    row = TABLE[worst["evidence"]["row"] - 1].cause if worst["cause"] == "startup" else None
    assert worst["cause"] in TRANSPORT_CAUSES or row in TRANSPORT_CAUSES, worst
    assert verdict, err[-2000:]
    assert "worst:" in verdict[-1] and stalls[0]["cause"] in verdict[-1], verdict
    assert s["verdict"]["outcome"] == "FAIL" and stalls[0]["owner"] == "system", s["verdict"]

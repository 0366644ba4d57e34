"""Failure handling of the real pair: SIGKILL of the controller, SIGINT of ``hil run``."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from hil.folder.recording import list_topics, read_messages
from tests.procs import wait_until
from tests.run_helpers import (
    PASSES,
    alive,
    check_verdict,
    children_of,
    clean_scenario,
    cmdline,
    load_log,
    rows_in,
)

pytestmark = pytest.mark.realtime


def _start_run(spawn, out, *args: str) -> subprocess.Popen:
    return spawn.python(["-m", "hil", "run", *args, "--quiet", "--out", str(out)])


def _child(pid: int, module: str) -> int | None:
    for c in children_of(pid):
        if module in cmdline(c):
            return c
    return None


def _running(out, name: str) -> bool:
    try:
        return "running" in (out / f"{name}.log").read_text()
    except OSError:
        return False


@pytest.mark.parametrize("path", ["zenoh", "can"])
def test_sigkill_of_controller_zeroes_torque_within_command_timeout(spawn, tmp_path, path):
    out = tmp_path / "run"
    rate = 200
    run = _start_run(spawn, out, "--duration", "4", "--rate", str(rate), "--cmd-path", path)
    assert wait_until(lambda: _running(out, "controller") and _running(out, "plant"), 60)
    ctrl = _child(run.pid, "controller_service")
    assert ctrl is not None
    # A closed loop first: wait until the plant has landed 100 commands (its streamed log).
    assert wait_until(lambda: rows_in(out / "plant.hoplog", "apply") >= 100, 30)
    os.kill(ctrl, signal.SIGKILL)
    run.wait(timeout=120)
    plog = load_log(out / "plant.hoplog")
    settings = json.loads((out / "run_settings.json").read_text())
    timeout_ns = int(settings["command_timeout"] * 1e9)
    applied = plog.table("apply")
    assert len(applied) >= 100, "too few commands applied before the kill"
    last_recv = max(a["recv_ns"] for a in applied)
    zeros = [z for z in plog.table("zero") if z["timeout_ns"] >= last_recv]
    assert zeros, "the plant never zeroed the torque after the controller died"
    # In model time: exactly command_timeout after the last command arrived ...
    assert zeros[0]["timeout_ns"] - last_recv == timeout_ns
    # ... and on the wall clock: in force at most command_timeout + 2 periods after it.
    wall = zeros[0]["applied_ns"] - last_recv
    assert wall <= timeout_ns + 2 * 1e9 / rate, f"zero torque in force {wall / 1e6:.2f} ms after"
    # Every state sampled after that moment shows zero applied torque.
    samples = plog.table("samples")
    after = [s for s in samples if s["sample_ns"] > last_recv + timeout_ns]
    assert len(after) > 50
    assert all(s["cmd1"] == 0.0 and s["cmd2"] == 0.0 for s in after)
    before = [s for s in samples if s["sample_ns"] < last_recv]
    assert any(s["cmd1"] != 0.0 for s in before)
    if path == "can":
        # the drives' counters: in the summary's can object, and in the plant's Status
        summary = json.loads((out / "summary.json").read_text())
        drives = summary["can"]["plant"]
        assert drives["frames_in"] >= 100 and drives["frames_out"] > 0
        assert drives["own_frames"] == 0 and drives["ignored"] == {}
        assert drives["rejections"] == {}, drives
        assert set(drives["drives"]) == {"0", "1"}
        statuses = [
            m.data
            for m in read_messages(out / "recording.mcap", topics=["hil/robot0/status"])
            if m.data.get("role") == "plant" and m.data.get("state") != "ready"  # not the gate's
        ]
        assert statuses and any(s["counters"].get("can_rx", 0) > 0 for s in statuses)
        assert all("can_n1_state" in s["counters"] for s in statuses)


def test_sigint_of_hil_run_leaves_no_process_and_a_readable_recording(spawn, tmp_path):
    out = tmp_path / "run"
    # A clean loop (CLEAN_50HZ at 100 Hz, D* = 498 ms): what runs before the interrupt PASSes.
    run = _start_run(spawn, out, str(clean_scenario(tmp_path)), "--duration", "60", "--rate",
                     "100")  # fmt: skip
    assert wait_until(lambda: _running(out, "controller") and _running(out, "plant"), 60)
    kids = children_of(run.pid)
    assert len(kids) >= 2
    # A closed loop to record first: 100 samples in the plant's streamed log.
    assert wait_until(lambda: rows_in(out / "plant.hoplog", "samples") >= 100, 30)
    run.send_signal(signal.SIGINT)
    code = run.wait(timeout=60)
    err = run.stderr.read().decode(errors="replace")
    assert code == 130, err[-3000:]  # interrupted: the contract's code, whatever typer/click do
    assert f"interrupted: run folder written to {out}" in err
    assert wait_until(lambda: not any(alive(k) for k in kids), 10)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True
    assert summary["samples"] > 50
    # A run cut short says so and gives what ran, not the 60 s planned; its verdict covers that.
    # What ran is the plant's window: its first to its last sample slot, from its own log (a
    # stalled plant skips slots, so it may exceed the samples' count times the period).
    settings = json.loads((out / "run_settings.json").read_text())
    slots = load_log(out / "plant.hoplog").columns("samples")["sample_ns"]
    ran = (max(slots) - min(slots)) / 1e9
    assert summary["duration_planned_s"] == 60.0
    assert abs(summary["duration_run_s"] - ran) <= 1e-6, (summary["duration_run_s"], ran)
    assert ran >= (summary["samples"] - 1) * settings["sensor_ts"] - 1e-6
    assert ran < 30.0  # the interrupt came long before the 60 s planned
    assert summary["duration"] == summary["duration_run_s"]
    assert any(n.startswith("interrupted after") for n in summary["verdict"]["notes"])
    # Nothing injected: what ran is a clean run's, PASS (its exit is the interrupt's, 130).
    check_verdict(summary, PASSES, None, out)
    report = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out), "--no-ideal"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    judged = json.loads((out / "report.json").read_text())
    check_verdict(judged, PASSES, report.returncode, out, command="report", context=report.stderr)
    head = (out / "report.md").read_text()[:4000]
    assert f"interrupted after {summary['duration_run_s']:.3f} s of 60 s" in head
    topics = list_topics(out / "recording.mcap")
    assert topics.get("hil/robot0/state", 0) > 50
    first = next(read_messages(out / "recording.mcap", topics=["hil/robot0/cmd/torque"]))
    assert first.data["type"] == "TorqueCommand"
    assert abs(first.data["tau1"]) <= 1.0  # CLEAN_50HZ's varpi1


def test_sigkill_of_hil_run_takes_the_children_down(spawn, tmp_path):
    out = tmp_path / "run"
    run = _start_run(spawn, out, "--duration", "60", "--rate", "100")
    assert wait_until(lambda: _running(out, "controller") and _running(out, "plant"), 60)
    kids = children_of(run.pid)
    assert len(kids) >= 2
    run.send_signal(signal.SIGKILL)
    run.wait(timeout=10)
    # PR_SET_PDEATHSIG: the kernel signals the children when their parent dies.
    assert wait_until(lambda: not any(alive(k) for k in kids), 15), [cmdline(k) for k in kids]


def test_bad_cmd_path_is_a_usage_error(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--cmd-path", "pigeon", "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "cmd-path" in proc.stderr

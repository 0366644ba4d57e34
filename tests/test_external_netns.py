"""An outside device beside a run with ``[impair]``: the run is in its own network namespace
(``unshare --net``), whose loopback nothing outside reaches; the run says how to join it
(``nsenter --net=/proc/PID/ns/net``), and a device started so connects and is judged."""

from __future__ import annotations

import json
import os
import shutil
import sys

import pytest

from hil.folder import layout
from tests.external_helpers import EXAMPLES, can_device_arrived, judged, odrive_can_device
from tests.procs import Lines, free_tcp_port, stop_pid, wait_until


def _why_not() -> str | None:
    if os.geteuid() != 0:
        return "needs root: [impair] runs hil run in its own network namespace"
    for tool in ("unshare", "ip", "nft", "nsenter"):
        if shutil.which(tool) is None:
            return f"{tool} not installed"
    return None


pytestmark = pytest.mark.skipif(_why_not() is not None, reason=_why_not() or "")


def _joined(spawn, tmp_path, impair_on: str, run_args: list[str], device: list[str]):
    """``hil run --controller external`` of a scenario with ``[impair] on = IMPAIR_ON``; once it
    says how to join its namespace, ``device`` (argv after the interpreter) started so; the
    run's exit code, its stderr lines and its PID (the device stopped by its PID)."""
    scenario = tmp_path / "impaired.toml"
    scenario.write_text(f'base = "paper_tracking"\n\n[impair]\non = "{impair_on}"\nloss = 0.0\n')
    argv = ["-m", "hil", "run", str(scenario), "--controller", "external", "--duration", "2"]
    run = spawn.python([*argv, *run_args, "--out", str(tmp_path / "run"), "--quiet"], text=True)
    err = Lines(run.stderr)
    assert wait_until(lambda: err.seen("waiting up to") or run.poll() is not None, 120)
    join = f"nsenter --net=/proc/{run.pid}/ns/net"
    assert f"{join} -- YOUR-DEVICE" in err.text(), err.text()
    proc = spawn.start([*join.split(), "--", sys.executable, *device])
    try:
        code = run.wait(timeout=240)
    finally:
        stop_pid(proc)
    return code, err, run.pid


def test_a_device_joins_the_runs_own_namespace_as_it_is_told(tmp_path, spawn):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    device = [str(EXAMPLES / "zenoh_controller.py"), endpoint]
    code, err, pid = _joined(spawn, tmp_path, "zenoh", ["--zenoh-endpoint", endpoint], device)
    out = tmp_path / "run"
    assert "device connected after" in err.text(5), err.text()
    assert json.loads((out / layout.DEVICE).read_text())["netns_pid"] == pid
    summary = json.loads((out / layout.SUMMARY).read_text())
    judged(out, code)
    assert summary["device"]["response"]["count"] > 100
    assert summary["max_abs_v"] > 0.2  # the device's commands moved the robot


GROUP = "239.74.163.2"  # a udp_multicast group, only ever inside the run's namespace


def test_a_can_device_on_udp_multicast_joins_the_runs_namespace(tmp_path, spawn):
    """python-can's udp_multicast, the bench's CAN bus between processes without vcan, only
    inside a private namespace: the odrive-can client joins the run's and drives the drives."""
    bus = ["--can-interface", "udp_multicast", "--can-channel", GROUP]
    device = [odrive_can_device()[0], "--interface", "udp_multicast", "--channel", GROUP]
    code, err, _ = _joined(spawn, tmp_path, "can", ["--cmd-path", "can", *bus], device)
    out = tmp_path / "run"
    assert can_device_arrived(err.text(5)), err.text()
    summary = json.loads((out / layout.SUMMARY).read_text())
    judged(out, code)
    dev = summary["device"]
    assert dev["path"] == "can" and dev["bus"]["armed"] >= 2
    assert sum(s["commands"] for s in dev["streams"]) > 200  # each wheel at 100 Hz for 2 s

"""``hil run --controller external --lab``: the plant and the recorder on one lab host, the
outside device on another (started with ``hil lab exec``), their messages through the two hosts'
routers, the hosts' clocks seconds apart. Every figure of the device is the plant's clock alone:
no clock of the device's is read, so no offset enters them."""

from __future__ import annotations

import json
import sys

import pytest

from hil.folder import layout
from tests.external_helpers import EXAMPLES, judged
from tests.lab_helpers import lab, lab_argv, lab_name, lab_skip_reason
from tests.procs import Lines, stop_pid, wait_until

pytestmark = pytest.mark.skipif(lab_skip_reason() is not None, reason=lab_skip_reason() or "")
OFFSET_S = {"h1": 3.2, "h2": -1.7}
HOST_ROUTER = "tcp/127.0.0.1:7447"  # a lab host's own router, from inside it (docs/lab.md)


def test_an_outside_device_on_another_lab_host_is_judged_on_the_plants_clock(tmp_path, spawn):
    name = lab_name("x")
    out = tmp_path / "run"
    offsets = [f"--offset={h}={o}" for h, o in OFFSET_S.items()]
    with lab(name, "--hosts", "2", *offsets):
        argv = ["-m", "hil", "run", "--controller", "external", "--lab", name]
        argv += ["--plant-host", "h1", "--controller-host", "h2", "--duration", "2"]
        argv += ["--out", str(out), "--quiet"]
        run = spawn.python(argv, text=True)
        err = Lines(run.stderr)
        assert wait_until(lambda: err.seen("waiting up to") or run.poll() is not None, 120)
        told = f"on lab {name}'s host h2: hil lab exec h2 --name {name} -- YOUR-DEVICE"
        assert told in err.text(), err.text()
        device = spawn.start(
            lab_argv(name, "h2", sys.executable, str(EXAMPLES / "zenoh_controller.py"), HOST_ROUTER)
        )
        try:
            code = run.wait(timeout=240)
        finally:
            stop_pid(device)
    assert "device connected after" in err.text(5), err.text()
    topo = json.loads((out / layout.TOPOLOGY).read_text())
    assert topo["processes"] == {"plant": "h1", "device": "h2", "recorder": "h1"}
    assert topo["router_hops"]["command"] == ["router@h2", "router@h1"]
    assert topo["clock"]["cross_host_figures"] == []
    summary = json.loads((out / layout.SUMMARY).read_text())
    judged(out, code)
    dev = summary["device"]
    assert dev["outside"] and dev["path"] == "zenoh"
    # The response time, State send to the command's arrival, both on h1's clock: a flight
    # through two routers and the device's compute, never the hosts' 4.9 s apart.
    response = dev["response"]
    assert response["count"] > 100, response
    assert 0 < response["p50_us"] < 1e6, response
    # the device's commands reached the plant across the hosts and were applied
    assert summary["max_abs_v"] > 0.2

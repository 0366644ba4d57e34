"""``hil controller`` and ``hil emulator`` started on their own around a Zenoh router."""

from __future__ import annotations

import time

import pytest

from tests.procs import free_tcp_port
from tests.run_helpers import load_log

pytestmark = pytest.mark.realtime

ROUTER = (
    "import sys, time, zenoh; from runtime.zsession import session_config; "
    "s = zenoh.open(session_config(sys.argv[1], listen_endpoint=True, mode='router')); "
    "print('up', flush=True); time.sleep(1e9)"
)


def test_standalone_services_close_the_loop_through_a_router(spawn, tmp_path):
    ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    can_ep = f"tcp/127.0.0.1:{free_tcp_port()}"
    router = spawn.python(["-c", ROUTER, ep], text=True)
    assert router.stdout.readline().strip() == "up"
    epoch = time.monotonic_ns() + 8_000_000_000  # both import and link well before t = 0
    common = ["paper_tracking", "--endpoint", ep, "--can-endpoint", can_ep,
              "--epoch-ns", str(epoch), "--duration", "1.5", "--rate", "200"]  # fmt: skip
    plant = spawn.python(["-m", "hil", "emulator", *common, "--out", str(tmp_path / "p")])
    ctrl = spawn.python(["-m", "hil", "controller", *common, "--out", str(tmp_path / "c")])
    plant.wait(timeout=60)
    assert plant.returncode == 0, plant.stderr.read()[-2000:]
    ctrl.send_signal(2)  # the controller runs until stopped (or duration + 2 s)
    ctrl.wait(timeout=30)
    clog = load_log(tmp_path / "c" / "controller.hoplog")
    plog = load_log(tmp_path / "p" / "plant.hoplog")
    assert clog.complete and plog.complete  # both exited cleanly: their footers are there
    assert clog.meta["epoch_ns"] == plog.meta["epoch_ns"] == epoch
    assert clog.info["state_counts"]["accepted"] > 200  # ~300 states in 1.5 s at 200 Hz
    assert plog.info["cmd_counts"]["accepted"] > 200

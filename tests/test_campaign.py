"""``hil campaign``: an outside device measured run after run with a growing delay added on the
feedback path toward it. Known answer: an added delay of X raises the
device's response time (the plant's send of a State to the arrival of the command naming it,
both on the plant's clock) by X."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from hil.commands.campaign import CAMPAIGN_JSON, CAMPAIGN_MD, values
from hil.folder import layout
from protocol.hoplog import read_hoplog
from tests.external_helpers import zenoh_device
from tests.procs import free_tcp_port, stop_pid


def response_ms(run_dir) -> float:
    """Median response, read here from the plant's log alone (an independent reader)."""
    log = read_hoplog(run_dir / layout.PLANT_LOG)
    sent = {r["seq"]: r["send_ns"] for r in log.table("samples")}
    rx = [r for r in log.table("cmd_rx") if r["state_seq"] in sent]
    return float(np.median([(r["recv_ns"] - sent[r["state_seq"]]) / 1e6 for r in rx]))


def campaign(spawn, out, *args: str) -> subprocess.CompletedProcess:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    # A real-time device: its own response then does not move with the host's load (a
    # SCHED_OTHER device beside two CPU hogs answered 1.3 ms later in one run than another).
    argv = [a.replace("{endpoint}", endpoint) for a in zenoh_device("--fifo")]
    device = spawn.python(argv)
    try:
        return subprocess.run(
            [
                sys.executable,
                "-m",
                "hil",
                "campaign",
                "--zenoh-endpoint",
                endpoint,
                "--duration",
                "2",
                "--out",
                str(out),
                *args,
            ],
            capture_output=True,
            text=True,
            timeout=400,
        )
    finally:
        stop_pid(device)


def test_values_cover_the_range():
    assert values(0.01, 0.03) == [0.0, 0.01, 0.02, 0.03]
    assert values(0.002, 0.005) == [0.0, 0.002, 0.004]


def test_an_added_delay_raises_the_response_time_by_itself(tmp_path, spawn):
    out = tmp_path / "campaign"
    p = campaign(spawn, out, "--step", "0.01", "--end", "0.02")
    assert p.returncode == 0, p.stderr
    doc = json.loads((out / CAMPAIGN_JSON).read_text())
    assert [s["value"] for s in doc["steps"]] == [0.0, 0.01, 0.02]
    # the device asks a small constant torque: nothing breaks, the whole range held
    assert doc["largest_held"] == 0.02 and doc["first_broken"] is None
    assert "largest delay added that held: 20 ms" in (out / CAMPAIGN_MD).read_text()
    base = response_ms(out / "run-000")
    steps = doc["steps"]
    for k, added_ms in ((1, 10.0), (2, 20.0)):
        raised = response_ms(out / f"run-{k:03d}") - base
        assert abs(raised - added_ms) < 0.5, (k, base, raised)
        # the bench's own figure (summary.json device.response, campaign.json) agrees
        moved = steps[k]["response_p50_ms"] - steps[0]["response_p50_ms"]
        assert abs(moved - added_ms) < 0.5, (k, steps[0]["response_p50_ms"], moved)


def test_a_break_at_the_start_is_a_fail_with_no_margin(tmp_path, spawn):
    out = tmp_path / "campaign"
    # the device does not track the reference at all: a 1 mm tracking bound breaks at once
    p = campaign(spawn, out, "--step", "0.01", "--end", "0.02", "--tracking-bound", "0.001")
    assert p.returncode == 1, p.stderr
    doc = json.loads((out / CAMPAIGN_JSON).read_text())
    assert len(doc["steps"]) == 1 and doc["steps"][0]["broken"] == ["tracking"]
    assert doc["largest_held"] is None and doc["first_broken"] == 0.0
    assert "broke a limit with nothing added" in p.stdout + p.stderr

"""Faults toward an outside device and its reaction, recorded: a drive that disarms with an
over-speed error ([faults] drive_fault_at), drives that stop answering ([faults]
drive_silent_*), encoder estimates frozen ([faults] feedback_frozen_*). The device is the
odrive-can client (tests/devices/odrive_can_device.py)."""

from __future__ import annotations

import json

import numpy as np

from hil.folder import layout
from protocol.hoplog import read_hoplog
from tests.external_helpers import judged, odrive_can_device, run_external


def run_with_faults(tmp_path, spawn, faults: str, *device_args: str):
    scenario = tmp_path / "faulty.toml"
    scenario.write_text(f'base = "paper_tracking"\n\n[faults]\n{faults}\n')
    out = tmp_path / "run"
    # the default run's transports (zenoh_can, 500 Hz), with the faults
    args = ("--cmd-path", "can", "--can-interface", "zenoh_can", "--rate", "500")
    code, _, _err = run_external(
        spawn, out, odrive_can_device(*device_args), duration=2.5, run_args=(*args, str(scenario))
    )
    judged(out, code)
    return out, json.loads((out / layout.SUMMARY).read_text())


def test_a_device_that_rearms_after_an_overspeed_trip(tmp_path, spawn):
    _out, summary = run_with_faults(
        tmp_path, spawn, "drive_fault_at = 1.0\ndrive_fault_node = 0", "--rearm"
    )
    (r,) = summary["drive_reactions"]
    assert r["node"] == 0 and r["error_names"] == "VELOCITY_LIMIT_VIOLATION"
    assert abs(r["t_s"] - 1.0) < 0.05
    # it learns of the trip from a heartbeat (every 100 ms), then clears and re-arms
    assert r["clear_errors_after_ms"] is not None and r["clear_errors_after_ms"] < 400
    assert r["armed_after_ms"] is not None and r["armed_after_ms"] >= r["clear_errors_after_ms"]
    assert not r["kept_commanding"]
    assert r["sentence"] in summary["verdict"]["notes"]
    assert "armed again after" in r["sentence"]


def test_a_device_that_keeps_commanding_a_disarmed_drive(tmp_path, spawn):
    _, summary = run_with_faults(tmp_path, spawn, "drive_fault_at = 1.0\ndrive_fault_node = 1")
    (r,) = summary["drive_reactions"]
    assert r["node"] == 1 and r["armed_after_ms"] is None
    assert r["kept_commanding"] and r["inputs_while_disarmed"] > 50  # 100 Hz for ~1.5 s
    assert "never re-armed" in r["sentence"] and "kept commanding" in r["sentence"]


def test_no_fault_no_reaction(tmp_path, spawn):
    _, summary = run_with_faults(tmp_path, spawn, "seed = 0")
    assert summary["drive_reactions"] == []


def test_silent_drives_leave_the_device_without_feedback(tmp_path, spawn):
    """The drives send nothing for 300 ms: a device that answers each encoder frame sends
    nothing either, a gap the plant's log shows on each wheel."""
    out, _summary = run_with_faults(
        tmp_path, spawn, "drive_silent_every = 2.0\ndrive_silent_length = 0.3\nseed = 3"
    )
    log = read_hoplog(out / layout.PLANT_LOG)
    assert log.final["can"]["silenced_frames"] > 20  # 2 drives x 100 Hz x 0.3 s, and heartbeats
    rx = log.table("cmd_rx")
    for node in (0, 1):
        t = np.array([r["recv_ns"] for r in rx if r["node"] == node]) / 1e9
        assert t.size > 100
        # 300 ms silent, +-1 encoder period (10 ms) for where the silence falls in it
        assert 0.28 < np.diff(t).max() < 0.33, np.diff(t).max()


def test_frozen_estimates_go_out_on_time_with_stale_content(tmp_path, spawn):
    """For 300 ms the drives' estimates carry the content of the last one before: the device
    keeps answering each on time (no gap), and the age bound of what it applied grows through
    the burst (the plant's log keeps each estimate's content time)."""
    out, summary = run_with_faults(
        tmp_path, spawn, "feedback_frozen_every = 2.0\nfeedback_frozen_length = 0.3\nseed = 3"
    )
    log = read_hoplog(out / layout.PLANT_LOG)
    frozen = log.final["can"]["frozen_frames"]
    assert 40 <= frozen <= 70, frozen  # 2 drives x 100 Hz x 0.3 s (+-1 per node, requests)
    enc = log.table("enc_tx")
    for node in (0, 1):
        mine = [r for r in enc if r["node"] == node]
        send = np.array([r["send_ns"] for r in mine]) / 1e9
        content = np.array([r["sample_ns"] for r in mine]) / 1e9
        # sent on time throughout: no silence in the sends
        assert np.diff(send).max() < 0.1, np.diff(send).max()
        # The stale content: the burst's frames carry the content of the last fresh estimate,
        # 300 ms on (+-1 period) from it. Measured from that fresh frame's own send, not from
        # its content's time: on a loaded host the plant may send an estimate late after taking
        # it (CI: 80 ms), which adds to every age but is no part of the freeze.
        runs = np.flatnonzero(np.diff(content) != 0.0) + 1  # where the content changes
        starts, ends = np.r_[0, runs], np.r_[runs, content.size] - 1
        frozen_for = (send[ends] - send[starts]).max()
        assert 0.27 < frozen_for < 0.32, frozen_for
        assert (send - content).max() >= frozen_for  # and at least that old at its send
    # what the device applied was at least that old by the burst's end
    age = summary["device"]["age"]
    assert age["max_us"] > 270_000, age

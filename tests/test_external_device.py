"""``hil run --controller external``: an outside device, a process that shares no code with the
bench, is the controller; the run says how to connect, waits for it, and writes the same run
folder as any run."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from hil.folder import layout
from protocol.hoplog import read_hoplog
from tests.external_helpers import (
    CAN_ARRIVALS,
    can_device_arrived,
    device_json,
    example_controller,
    foreign_can_frames,
    judged,
    odrive_can_device,
    report_again,
    run_external,
)
from tests.procs import Lines, free_tcp_port, stop_pid, wait_until


def test_no_device_is_a_fail_with_the_folder_written(tmp_path, spawn):
    out = tmp_path / "run"
    proc = spawn.python(
        [
            "-m",
            "hil",
            "run",
            "--controller",
            "external",
            "--duration",
            "2",
            "--wait-device",
            "2",
            "--out",
            str(out),
            "--quiet",
        ],
        text=True,
    )
    _, err = proc.communicate(timeout=180)
    assert proc.returncode == 1, err
    assert "no device connected within 2 s: nothing subscribed to hil/robot0/state" in err
    conn = device_json(out)
    assert conn["path"] == "zenoh" and conn["connected_after_s"] is None
    assert conn["zenoh"]["state_key"] == "hil/robot0/state"
    assert conn["zenoh"]["command_key"] == "hil/robot0/cmd/torque"
    summary = json.loads((out / layout.SUMMARY).read_text())
    assert summary["verdict"]["outcome"] == "FAIL"
    # no controller of the bench's ran
    assert not (out / layout.CONTROLLER_OUTPUT).exists()
    assert "controller" not in json.loads((out / layout.PROCESSES).read_text())


@pytest.mark.parametrize(
    "args",
    [
        ["--controller", "robot"],
        ["--controller", "external", "--lockstep"],
        ["--controller", "external", "--law", "pd"],
        ["--controller", "external", "--zenoh-endpoint", "udp/1.2.3.4"],
        ["--controller", "external", "--wait-device", "0"],
    ],
)
def test_bad_device_options_exit_2_before_anything_runs(tmp_path, args):
    out = tmp_path / "run"
    p = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--out", str(out), *args],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2, p.stderr
    assert not out.exists()


def test_the_example_controller_runs_and_is_judged(tmp_path, spawn):
    out = tmp_path / "run"
    code, _, err = run_external(spawn, out, example_controller(), duration=2.0)
    assert "device connected after" in err, err
    assert "connect to tcp/127.0.0.1:" in err
    conn = device_json(out)
    assert conn["connected_after_s"] is not None and "subscriber" in conn["how"]
    for name in (*layout.REQUIRED, layout.RECORDING, layout.PLANT_LOG, layout.REPORT_HTML):
        assert (out / name).is_file(), name
    assert not (out / layout.CONTROLLER_LOG).exists()
    # The device's commands reached the plant and were applied: about one per State.
    log = read_hoplog(out / layout.PLANT_LOG)
    samples, rx = log.table("samples"), log.table("cmd_rx")
    assert len(samples) > 500
    # the device answers States (a loaded host makes it miss some: how many is its figure,
    # judged by the verdict, not this test's); the bench applied what arrived (a command
    # still waiting for its landing when the plant stopped has no fate)
    assert len(rx) > 0.5 * len(samples)
    fates = log.table("apply")
    assert len(fates) <= len(rx)
    assert sum(r["outcome"] == 0 for r in fates) > 0.5 * len(samples)
    # It asked 0.5 m/s: the robot moved (the bench applied what it asked).
    summary = json.loads((out / layout.SUMMARY).read_text())
    judged(out, code)
    assert summary["max_abs_v"] > 0.2
    # hil report reads the folder
    assert report_again(out) == code  # the saved verdict, read again


def test_an_odrive_can_client_drives_the_virtual_odrives(tmp_path, spawn):
    """Device (a): the PyPI odrive-can client arms both drives and sends a torque per encoder
    frame; the run waits for the arming, lands the frames, and writes a folder hil report
    reads."""
    out = tmp_path / "run"
    code, _, err = run_external(
        spawn, out, odrive_can_device(), duration=2.0, run_args=("--cmd-path", "can")
    )
    assert can_device_arrived(err), err
    conn = device_json(out)
    assert conn["how"] in CAN_ARRIVALS, conn["how"]
    assert conn["path"] == "can" and conn["can"]["node_left"] == 0
    assert conn["can"]["zenoh_can_endpoint"].startswith("tcp/127.0.0.1:")
    log = read_hoplog(out / layout.PLANT_LOG)
    rx = log.table("cmd_rx")
    per_node = {n: sum(1 for r in rx if r["node"] == n) for n in (0, 1)}
    # one torque per encoder frame of each wheel (the drives send them every 10 ms): 2 s
    assert min(per_node.values()) > 100, per_node
    drives = log.final["can"]["drives"]
    assert {d["axis_state"] for d in drives.values()} == {8}  # both armed
    judged(out, code)
    # judged at its own 100 Hz (the estimates' rate), not the plant's 500 Hz: once, every
    # interval was a 'gap' and 80 % of the samples fell in them (FAIL by construction)
    dev = json.loads((out / layout.SUMMARY).read_text())["device"]
    assert dev["nominal_period_from"] == "device median"
    assert abs(dev["nominal_period_s"] - 0.010) < 0.001, dev["nominal_period_s"]
    assert dev["samples_in_gaps"] < 0.2 * dev["samples_judged"], dev
    for name in (*layout.REQUIRED, layout.REPORT_HTML):
        assert (out / name).is_file(), name


def test_frames_that_arm_nothing_are_a_fail_and_foreign_ones_no_command(tmp_path, spawn):
    """A device that sends torques to an idle drive, another node's torques and an extended
    frame whose low bits read as one: the run's logs stay readable (a foreign node number once
    made the plant's log unreadable and the verdict a PASS of nothing measured), only the
    drives' own frames are arrivals, and the verdict is a FAIL of the device."""
    out = tmp_path / "run"
    code, stdout, err = run_external(
        spawn, out, foreign_can_frames(), duration=2.0, run_args=("--cmd-path", "can")
    )
    summary = json.loads((out / layout.SUMMARY).read_text())
    assert "logs_unreadable" not in summary, summary["logs_unreadable"]
    rx = read_hoplog(out / layout.PLANT_LOG).table("cmd_rx")
    nodes = {r["node"] for r in rx}
    assert nodes == {0}, nodes  # the idle drive's own frames, nothing of node 28 or extended
    can = summary["can"]["plant"]
    assert can["ignored"].get("other_node", 0) > 0 and can["ignored"].get("extended_id", 0) > 0
    verdict = summary["verdict"]
    assert verdict["outcome"] == "FAIL" and code == 1, (code, stdout, err)
    assert any("never armed the drives" in r for r in verdict["fail_reasons"]), verdict


def test_hil_drives_is_the_recorded_session(tmp_path, spawn):
    """``hil drives`` is ``hil run --controller external --cmd-path can --until-stopped`` into
    runs/drives-* (or --record DIR): the odrive-can client arms the drives and drives them,
    Ctrl-C (here SIGINT) is the planned end, and the folder is a judged run folder that hil
    report reads."""
    bus = f"tcp/127.0.0.1:{free_tcp_port()}"
    argv = ["-m", "hil", "drives", "--can-endpoint", bus]
    drives = spawn.python(argv, text=True, cwd=tmp_path)
    err = Lines(drives.stderr)
    assert wait_until(lambda: err.seen("waiting up to") or drives.poll() is not None, 120)
    device = spawn.python([*odrive_can_device()[:2], bus], text=True)
    try:
        assert wait_until(lambda: err.seen("the run starts") or drives.poll() is not None, 60)
        # the session runs until stopped: 2 s of the device's commands, then Ctrl-C
        assert wait_until(lambda: drives.poll() is not None, 2.0) is False
        drives.send_signal(signal.SIGINT)
        code = drives.wait(timeout=240)
    finally:
        stop_pid(device)
    (out,) = (tmp_path / "runs").glob("drives-*")  # the default folder, and nothing else
    summary = json.loads((out / layout.SUMMARY).read_text())
    assert summary["until_stopped"] is True and summary["cmd_path"] == "can"
    assert summary["duration_run_s"] > 1.0
    judged(out, code)
    assert device_json(out)["path"] == "can"
    dev = summary["device"]
    assert dev["outside"] and sum(s["commands"] for s in dev["streams"]) > 200  # 100 Hz x 2
    assert report_again(out) == code  # the saved verdict, read again


@pytest.mark.parametrize("option", [["--heartbeat-ms", "50"], ["--node-left", "3"]])
def test_hil_drives_record_refuses_what_it_would_not_honour(tmp_path, option):
    out = tmp_path / "rec"
    p = subprocess.run(
        [sys.executable, "-m", "hil", "drives", "--record", str(out), *option],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2 and "is the light form's (--no-record)" in p.stderr, p.stderr
    assert not out.exists()


def test_the_devices_share_no_code_with_the_bench():
    """The example controller and the test devices import only the standard library,
    eclipse-zenoh, msgpack, python-can and odrive-can: nothing of this project."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    ours = {"hil", "protocol", "runtime", "controller_service", "plant_emulator", "tests", "bench"}
    files = [
        root / "examples" / "zenoh_controller.py",
        *sorted((root / "tests" / "devices").glob("*.py")),
    ]
    assert len(files) >= 3
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            for name in names:
                assert name.split(".")[0] not in ours, (path.name, name)


def test_an_open_ended_session_ends_on_ctrl_c_with_a_judged_folder(tmp_path, spawn):
    """--until-stopped: the run lasts until SIGINT, its planned end (not exit 130)."""
    import signal
    import time

    from tests.external_helpers import zenoh_device
    from tests.procs import Lines, free_tcp_port, wait_until

    out = tmp_path / "run"
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    run = spawn.python(
        [
            "-m",
            "hil",
            "run",
            "--controller",
            "external",
            "--until-stopped",
            "--out",
            str(out),
            "--zenoh-endpoint",
            endpoint,
            "--quiet",
        ],
        text=True,
    )
    err = Lines(run.stderr)
    assert wait_until(lambda: err.seen("until Ctrl-C"), 120), err.text()
    spawn.python([a.replace("{endpoint}", endpoint) for a in zenoh_device()])
    assert wait_until(lambda: err.seen("device connected"), 120), err.text()
    started = time.monotonic()
    # the plant has run a while: its hop log holds more than a second of samples
    assert wait_until(lambda: time.monotonic() - started > 1.5, 5)
    run.send_signal(signal.SIGINT)
    code = run.wait(timeout=240)
    judged(out, code)
    summary = json.loads((out / layout.SUMMARY).read_text())
    assert summary["until_stopped"] is True and summary["interrupted"] is False
    assert 1.0 < summary["duration"] < 60.0  # the session's length, not a planned one
    assert not any("interrupted" in n for n in summary["verdict"]["notes"])
    assert (out / layout.REPORT_HTML).is_file()


def test_until_stopped_takes_no_duration(tmp_path):
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "hil",
            "run",
            "--controller",
            "external",
            "--until-stopped",
            "--duration",
            "3",
            "--out",
            str(tmp_path / "r"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2 and "--until-stopped" in p.stderr

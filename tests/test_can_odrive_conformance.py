"""Conformance against clients nobody here wrote: the PyPI ``odrive-can`` client (2.1.0) drives
``hil drives`` (tests/odrive_client_session.py), and ``python -m can.logger`` on the same bus
logs frames that all decode with the shipped DBC. Over ``zenoh_can``, and over ``udp_multicast``
inside a private network namespace (``unshare -n``; lo up, multicast on, 224.0.0.0/4 via lo)."""

from __future__ import annotations

import json
import math
import os
import shlex
import signal
import sys
import tomllib
import uuid
from importlib import resources
from pathlib import Path

import can
import cantools
import pytest

from hil.bench.defaults import PAPER_TRACKING_TOML
from plant_emulator.odrive import CATCH_UP
from protocol.can import codec
from tests.procs import Lines, free_tcp_port, wait_until

pytestmark = pytest.mark.realtime

REPO = Path(__file__).resolve().parents[1]
WATCHDOG = 0.5
GROUP = "239.74.163.2"
DRIVES_OPTS = ["--watchdog-timeout", str(WATCHDOG), "--status-period", "0.5"]


def _last_json(text: str) -> dict:
    for line in reversed(text.strip().splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise AssertionError(f"no JSON line in:\n{text[-3000:]}")


def _check_session(res: dict) -> None:
    assert res["first_heartbeat"]["right"]["Axis_State"] == "IDLE"
    assert res["first_heartbeat"]["right"]["Axis_Error"] == "NONE"
    v = res["version"]
    assert v["Protocol_Version"] == 2
    assert (v["Fw_Version_Major"], v["Fw_Version_Minor"], v["Fw_Version_Revision"]) == (0, 6, 10)
    assert v["Fw_Version_Unreleased"] == 1  # a model, not an official firmware
    assert res["armed"] == {"right": "CLOSED_LOOP_CONTROL", "left": "CLOSED_LOOP_CONTROL"}

    # the robot starts at rest; 0.02 Nm forward on both wheels turns both motors forward
    assert res["forward"]["right_start"] == {"Pos_Estimate": 0.0, "Vel_Estimate": 0.0}
    for side in ("right", "left"):
        est = res["forward"][side]
        assert est["Vel_Estimate"] > 5.0 and est["Pos_Estimate"] > 1.0, est
    # Get_Torques, Get_Iq, Get_Powers, Get_Bus_Voltage_Current, Get_Error: the model's values
    assert res["torques"]["Torque_Target"] == pytest.approx(0.02, rel=1e-6)
    assert res["torques"]["Torque_Estimate"] == pytest.approx(0.02, rel=1e-6)
    # 0.02 Nm / 0.04 Nm/A (the firmware's torque_constant)
    assert res["iq"]["Iq_Setpoint"] == pytest.approx(0.5, rel=1e-6)
    assert res["iq"]["Iq_Measured"] == pytest.approx(0.5, rel=1e-6)
    mech = res["powers"]["Mechanical_Power"]
    vel = res["forward"]["right"]["Vel_Estimate"]
    assert mech == pytest.approx(0.02 * vel * 2 * math.pi, rel=0.05)
    assert res["powers"]["Electrical_Power"] > mech > 0.0
    assert res["bus"]["Bus_Voltage"] == 24.0
    assert res["bus"]["Bus_Current"] == pytest.approx(
        res["powers"]["Electrical_Power"] / 24.0, rel=0.05
    )
    assert res["error"] == {"Active_Errors": "NONE", "Disarm_Reason": "NONE"}
    assert res["temperature"] == {"FET_Temperature": 25.0, "Motor_Temperature": 25.0}

    # Coasting: the cyclic frames (every 10 ms) and the ten RTR answers come from one coasting
    # model. By content, not by the busy client's arrival stamps (a loaded host delays them; the
    # rates are bench/bench_drives.py's): one velocity in every frame (an answer of 0/0 would
    # break it), and the positions it covers give the drive's own time span, in which at most
    # a frame every 10 ms and the RTR answers fit (a grid sends nothing ahead of it; 2 for
    # the frames at the span's ends, and up to CATCH_UP = 5 frames due before the span that
    # a stall sent back to back at its start), and at least the answers and a cyclic frame.
    coast = res["coast"]
    assert coast["vel"] > 5.0 and coast["pos"] > 1.0
    assert coast["vel_dev"] < 1e-4
    most = coast["pos_span"] / coast["vel"] / 0.01 + coast["rtr_sent"] + 2 + CATCH_UP
    assert coast["rtr_sent"] + 1 <= coast["frames"] <= most, coast

    # right forward, left back: the right wheel speeds up, the left slows down (a left turn)
    assert res["turn"]["right"]["Vel_Estimate"] > vel + 2.0
    assert res["turn"]["left"]["Vel_Estimate"] < res["forward"]["left"]["Vel_Estimate"] - 2.0
    # Set_Limits: 1 A x 0.04 Nm/A clamps a 0.3 Nm set point
    assert res["limited_torques"]["Torque_Target"] == pytest.approx(0.04, rel=1e-6)
    # Set_Input_Vel in VELOCITY_CONTROL through the drive's velocity loop
    for side in ("right", "left"):
        assert res["velocity"][side]["Vel_Estimate"] == pytest.approx(5.0, rel=0.02)
    # Set_Absolute_Position, then POSITION_CONTROL to 2 rev further
    assert res["absolute"]["Pos_Estimate"] == pytest.approx(100.0, abs=0.1)
    assert res["position"]["Pos_Estimate"] == pytest.approx(res["position"]["target"], abs=0.01)

    # Estop: disarmed with ESTOP_REQUESTED, visible in the heartbeat and Get_Error; re-arming
    # is refused until Clear_Errors
    estop = res["estop"]
    assert estop["idle"] and estop["heartbeat"]["Axis_Error"] == "ESTOP_REQUESTED"
    assert estop["error"] == {
        "Active_Errors": "ESTOP_REQUESTED",
        "Disarm_Reason": "ESTOP_REQUESTED",
    }
    assert estop["check_errors"].startswith("DriveError")
    assert estop["rearm_refused"] == "IDLE"
    assert res["recovered"] == {"right": "CLOSED_LOOP_CONTROL", "left": "CLOSED_LOOP_CONTROL"}
    # A silent host: the watchdog disarms with WATCHDOG_TIMER_EXPIRED, never before WATCHDOG
    # after its last feed (stamped before that command left, on the same host's clock); how
    # soon after is the heartbeat's and the host's (within the wait's WATCHDOG + 1 s).
    wd = res["watchdog"]
    assert wd["idle"] and wd["since_feed_s"] >= WATCHDOG, wd
    assert wd["heartbeat"]["Axis_Error"] == "WATCHDOG_TIMER_EXPIRED"
    assert wd["error"]["Disarm_Reason"] == "WATCHDOG_TIMER_EXPIRED"
    assert res["idle_at_end"]


def _check_drives_summary(summary: dict, echoes: bool) -> None:
    c = summary["can"]
    # exactly what the session did wrong, by kind: re-arming under an estop, a 9 Nm torque to
    # an idle drive, a NaN torque and a 3-byte one
    assert c["rejections"] == {
        "arm_with_error": 1,
        "input_while_disarmed": 1,
        "non_finite": 1,
        "wrong_dlc": 1,
    }, c
    assert c["ignored"] == {}
    assert c["events"]["estop"] == 2 and c["events"]["watchdog_expired"] >= 1
    assert c["events"]["torque_clamped"] == 1
    assert c["requests"] >= 25  # every RTR of the session was answered by the edge at once
    assert (c["own_frames"] > 100) if echoes else (c["own_frames"] == 0)
    # the robot went forward along its initial heading and turned left (hil drives' default
    # scenario: hil run's, the bundled paper_tracking)
    start = tomllib.loads(PAPER_TRACKING_TOML)["initial"]
    final = summary["robot"]["final"]
    th0 = start["theta"]
    ahead = math.cos(th0) * (final["x"] - start["x"]) + math.sin(th0) * (final["y"] - start["y"])
    assert ahead > 0.2 and final["theta"] > th0 + 0.1, final
    assert summary["robot"]["violations"] == {"v": 0, "omega": 0, "tau1": 0, "tau2": 0}


def _check_log(path: Path) -> None:
    db = cantools.database.load_file(str(resources.files("protocol.can") / codec.DBC_NAME))
    nodes, kinds, n = set(), set(), 0
    with can.LogReader(str(path)) as reader:
        for msg in reader:
            n += 1
            dbc_msg = db.get_message_by_frame_id(msg.arbitration_id)  # KeyError: not in it
            if not msg.is_remote_frame and len(msg.data) == dbc_msg.length:
                dbc_msg.decode(bytes(msg.data))
            nodes.add(msg.arbitration_id >> 5)
            kinds.add(dbc_msg.name.split("_", 1)[1])
    assert n > 500 and nodes == {0, 1}
    for name in ("Heartbeat", "Get_Encoder_Estimates", "Set_Input_Torque", "Get_Version", "Estop"):
        assert name in kinds, name


def test_can_odrive_can_client_drives_hil_drives_over_zenoh_can(spawn, tmp_path):
    channel = f"t{uuid.uuid4().hex[:8]}"
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    bus = ["--channel", channel]
    drives = spawn.python(
        [
            "-m",
            "hil",
            "drives",
            "--no-record",
            "--can-interface",
            "zenoh_can",
            *bus,
            "--can-endpoint",
            endpoint,
            *DRIVES_OPTS,
        ],
        text=True,
        cwd=REPO,
    )
    out = Lines(drives.stdout)
    assert wait_until(lambda: out.seen("hil drives:"), 60), drives.stderr.read()
    log = tmp_path / "bus.log"
    logger = spawn.python(
        [
            *("-m", "can.logger", "-i", "zenoh_can", *bus),
            *("--bus-kwargs", f"endpoint={endpoint}", "-f", str(log)),
        ],
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},  # it prints "Connected" without a flush
    )
    logged = Lines(logger.stdout)
    assert wait_until(lambda: logged.seen("Connected"), 60)
    client = spawn.python(
        [
            "-m",
            "tests.odrive_client_session",
            "--interface",
            "zenoh_can",
            *bus,
            *("--endpoint", endpoint, "--watchdog", str(WATCHDOG)),
        ],
        text=True,
        cwd=REPO,
    )
    stdout, stderr = client.communicate(timeout=120)
    assert client.returncode == 0, stderr[-3000:]
    _check_session(_last_json(stdout))
    assert wait_until(lambda: out.seen("rx "), 10)  # the status line
    drives.send_signal(signal.SIGINT)
    assert drives.wait(timeout=10) == 0
    _check_drives_summary(_last_json(out.text(5.0))["summary"], echoes=False)
    logger.send_signal(signal.SIGINT)
    logger.wait(timeout=30)
    _check_log(log)


def test_can_odrive_can_client_drives_hil_drives_over_udp_multicast_in_a_netns(spawn, tmp_path):
    py = shlex.quote(sys.executable)
    # A background job of a non-interactive shell starts with SIGINT ignored, and Python then
    # installs no KeyboardInterrupt handler: can.logger would not stop (nor flush) on SIGINT.
    logger_cmd = shlex.quote(
        "import runpy, signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "sys.argv[0] = 'can.logger'; runpy.run_module('can.logger', run_name='__main__')"
    )
    t = shlex.quote(str(tmp_path))
    drives_opts = " ".join(DRIVES_OPTS)
    script = f"""
set -e
ip link set lo up
ip link set lo multicast on
ip route add 224.0.0.0/4 dev lo
cd {shlex.quote(str(REPO))}
{py} -m hil drives --no-record --can-interface udp_multicast --channel {GROUP} {drives_opts} \
    > {t}/drives.out 2> {t}/drives.err &
drives=$!
PYTHONUNBUFFERED=1 {py} -c {logger_cmd} -i udp_multicast -c {GROUP} -f {t}/bus.log \
    > {t}/logger.out 2>&1 &
logger=$!
n=0
until grep -q "hil drives:" {t}/drives.out && grep -q Connected {t}/logger.out; do
    n=$((n + 1)); [ $n -lt 600 ] || exit 3; sleep 0.1
done
set +e
{py} -m tests.odrive_client_session --interface udp_multicast --channel {GROUP} \
    --watchdog {WATCHDOG} > {t}/client.out 2> {t}/client.err
rc=$?
kill -INT $drives $logger
wait $drives; echo "drives exit $?" >> {t}/drives.err
wait $logger
exit $rc
"""
    proc = spawn.start(["unshare", "-n", "sh", "-c", script], text=True)
    _, err = proc.communicate(timeout=240)
    files = {p.name: p.read_text() for p in tmp_path.glob("*.*") if p.suffix != ".log"}
    assert proc.returncode == 0, (err, files)
    _check_session(_last_json(files["client.out"]))
    assert "drives exit 0" in files["drives.err"], files["drives.err"]
    assert "udp_multicast 239.74.163.2" in files["drives.out"]  # no refusal inside the netns
    _check_drives_summary(_last_json(files["drives.out"])["summary"], echoes=True)
    _check_log(tmp_path / "bus.log")

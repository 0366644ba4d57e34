"""An outside device (b): a controller written in C against Linux SocketCAN
(examples/socketcan_controller.c, nothing of the bench), compiled with the system's gcc during
the test, drives the virtual ODrives of ``hil run --controller external --cmd-path can`` on a
real vcan0 (the QEMU guest lane), and the run ends in a folder that ``hil report`` reads.

The guest runs the bench's Python ~25x slower (TCG): the figures of its timing are not the
device's here, so this test asserts what the device controls (it armed, every frame it sent was
well-formed and landed, its torques acted and stayed in the limits) and that the folder is
written and judged, never a verdict of the bench's own fault (exit code 3)."""

from __future__ import annotations

import re

import pytest

from tests.external_helpers import can_device_arrived
from tests.socketcan_helpers import (
    C_CONTROLLER,
    CHANNEL,
    build_c_controller,
    run_devices,
    torques_within_limits,
)

INCLUDE = re.compile(r"^\s*#\s*include\s*[<\"]([^>\"]+)[>\"]", re.MULTILINE)

#: The device sends a torque per wheel at 20 Hz (-f 20, from the last encoder estimate): ~60
#: per wheel in a 3 s run; the guest's plant, in Python ~50x slower than native on a slow host,
#: read only ~70 frames a second (answering every estimate, its queue held ~1 s of them), so
#: 10 landed per wheel is enough to say it drove.
MIN_TORQUES = 10
DEVICE_LINE = re.compile(r"node (\d+): (\d+) estimates, (\d+) torques")


def test_the_c_controller_builds_and_includes_only_the_system(tmp_path):
    """It shares no code with the bench (libc and Linux headers only) and builds warning-free
    with the system's gcc, as its header says (here too, where the kernel has no CAN)."""
    headers = INCLUDE.findall(C_CONTROLLER.read_text())
    assert "linux/can.h" in headers and "linux/can/raw.h" in headers
    assert all(h.startswith(("linux/", "sys/", "net/")) or "/" not in h for h in headers), headers
    assert build_c_controller(tmp_path).is_file()


@pytest.mark.vcan
@pytest.mark.realtime
@pytest.mark.timeout(900)
def test_a_c_socketcan_controller_is_run_and_judged(tmp_path, spawn):
    binary = build_c_controller(tmp_path)
    device = [str(binary), "-i", CHANNEL, "-l", "0", "-r", "1", "-f", "20"]
    run = run_devices(spawn, tmp_path / "run", [device], duration=3.0)

    # The run waited for it and let it in: by its arming of both drives, or by the zero torque
    # it sends each drive just before (hil.bench.device: a first input frame also counts).
    assert can_device_arrived(run.stderr), run.stderr
    conn = run.device_json()
    assert conn["path"] == "can" and conn["connected_after_s"] is not None
    assert conn["can"]["interface"] == "socketcan" and conn["can"]["channel"] == CHANNEL

    # The device's own account: it armed, and stopped cleanly when stopped by its PID (SIGINT:
    # torque 0, Set_Axis_State IDLE, a summary line).
    dev_code, dev_out = run.devices[0]
    assert dev_code == 0, dev_out
    assert f"armed nodes 0 and 1 on {CHANNEL}" in dev_out, dev_out
    sent = {int(n): int(tq) for n, _, tq in DEVICE_LINE.findall(dev_out)}
    assert set(sent) == {0, 1}, dev_out

    log = run.plant()
    assert log.final is not None, "the plant did not end cleanly"
    can = log.final["can"]
    # Every frame it sent was CANSimple the drives accept: nothing refused, nothing unknown.
    assert can["rejections"] == {}, can["rejections"]
    assert can["ignored"] == {}, can["ignored"]
    assert {d["axis_state"] for d in can["drives"].values()} == {8}, can["drives"]
    # Its torques landed and were applied, one per encoder frame of each wheel; no more landed
    # than it sent (the +1: the zero torque it sends before arming).
    rx = log.table("cmd_rx")
    applied = [r for r in log.table("apply") if r["outcome"] == 0]
    for node in (0, 1):
        landed = sum(1 for r in rx if r["node"] == node)
        assert MIN_TORQUES <= landed <= sent[node] + 1, (node, landed, sent)
        assert sum(1 for r in applied if r["node"] == node) >= MIN_TORQUES
    # They acted: from rest its speed loop (5 motor rev/s asked) first sent positive torques,
    # and they moved the robot forward before anything else did. How well the loop then holds
    # 5 rev/s is the device's own: a second behind in the guest, it oscillates (seen: both
    # wheels at -77 rev/s after 3 s), as any P loop with that lag would.
    asked = {n: [r["tau1"] for r in rx if r["node"] == n and r["tau1"] != 0.0] for n in (0, 1)}
    assert all(q and q[0] > 0.0 for q in asked.values()), asked
    v = [r["v"] for r in log.table("samples")]
    assert next((x for x in v if abs(x) > 0.01), 0.0) > 0.0, v[:50]
    torques_within_limits(run)

    assert run.summary()["exit_codes"]["plant"] == 0, run.summary()["exit_codes"]
    verdict = run.judged()
    print(f"C device: hil run exit {run.code}; {run.stdout.strip()}; verdict {verdict}")

"""An outside device (d): can-utils' ``cangen`` sends garbage on the bus of ``hil run
--controller external --cmd-path can`` (SocketCAN vcan0, the QEMU guest lane): random ids,
lengths and payloads, RTR and extended frames, frames to the drives' own node ids with wrong
lengths, and torques of NaN, of float32's largest value and of random bits. Twice: beside a real
device (the C controller of examples/, as on a shared bus with a broken node), and alone.

Each time: nothing crashes (the plant exits 0, ``hil run`` exits with a verdict's code 0/1/4,
never 3), every garbage frame is counted where it belongs (ignored: another node's or an
extended frame; refused: a wrong length, a non-finite value), no torque outside the limits (2)
was applied, and the folder is one ``hil report`` reads.

Verdicts: garbage alone never armed a drive, so it is a FAIL ("no device connected", or,
when a frame with an input's id let it in, "the device never armed the drives", or "sent no
command the bench received" when none of its frames in the run was one), never a PASS;
beside the C device, ``hil report`` says what ``hil run`` judged (the verdict is judged once,
by the analysis).

Counts allow for the frames the plant's own socket dropped (``socket_drops``, the kernel's
count) or still held unread when the plant stopped (``unread_at_stop``; the guest's plant, in
Python ~25x slower, was 12 frames behind at its end on a loaded host): a garbage frame is
either counted or among those, and never counted twice."""

from __future__ import annotations

import re

import pytest

from tests.socketcan_helpers import (
    CHANNEL,
    DeviceRun,
    build_c_controller,
    report,
    require_program,
    run_devices,
    torques_within_limits,
)

pytestmark = [pytest.mark.vcan, pytest.mark.realtime, pytest.mark.timeout(900)]

NODES = (0, 1)
ADDRESS_REQUEST_ID = 0x3F << 5 | 0x06  # answered by every drive, not another node's frame
NAN_FRAMES = 20
HUGE_FRAMES = 20
SHORT_FRAMES = 4 * 20
#: (name, cangen options, frames): about 4 s each, ~175 frames/s together (the guest's plant
#: reads them in Python 25-50x slower than its host: at twice the rate its socket dropped most).
GARBAGE: tuple[tuple[str, tuple[str, ...], int], ...] = (
    ("random", ("-g", "16", "-I", "r", "-L", "r", "-D", "r", "-v"), 250),
    ("rtr", ("-g", "50", "-R", "-v"), 80),
    ("extended", ("-g", "50", "-e"), 80),
    # wrong lengths to the drives' own ids: Set_Input_Torque (4 bytes) with 2 and 3,
    # Set_Axis_State (4) with 1, Set_Controller_Mode (8) with 5
    ("short_torque_0", ("-g", "200", "-I", "00E", "-L", "2"), 20),
    ("short_torque_1", ("-g", "200", "-I", "02E", "-L", "3"), 20),
    ("short_state_1", ("-g", "200", "-I", "027", "-L", "1"), 20),
    ("short_mode_0", ("-g", "200", "-I", "00B", "-L", "5"), 20),
    # Set_Input_Torque of NaN (0x7FC00000), of 3.4e38 (0x7F7FFFFF), and of random bits
    ("nan_torque_0", ("-g", "200", "-I", "00E", "-L", "4", "-D", "0000C07F"), NAN_FRAMES),
    ("huge_torque_1", ("-g", "200", "-I", "02E", "-L", "4", "-D", "FFFF7F7F"), HUGE_FRAMES),
    ("random_torque_0", ("-g", "50", "-I", "00E", "-L", "4", "-D", "r"), 80),
    ("random_torque_1", ("-g", "50", "-I", "02E", "-L", "8", "-D", "r"), 80),
)
#: cangen -v prints each frame it sent in candump's compact form: "  vcan0  5A1#11.22.33", an
#: empty payload "5A1#", a remote frame "5A1#R" (a length may follow the R).
SENT = re.compile(r"^\s*\S+\s+([0-9A-F]{3})#(\S*)\s*$", re.MULTILINE)


def cangen_argvs() -> list[list[str]]:
    cangen = require_program("cangen", "can-utils")
    # -p: wait on a full queue rather than exit, so every frame asked for is sent
    return [[cangen, CHANNEL, *opts, "-p", "100", "-n", str(n)] for _, opts, n in GARBAGE]


def other_node_frames(run: DeviceRun) -> int:
    """The frames of cangen's verbose instances whose node is not a drive's (what the drives
    must ignore as another node's), from cangen's own list of what it sent."""
    count = 0
    verbose = [i for i, (_, opts, _) in enumerate(GARBAGE) if "-v" in opts]
    for i in verbose:
        _, text = run.devices[-len(GARBAGE) + i]
        frames = SENT.findall(text)
        assert len(frames) == GARBAGE[i][2], f"cangen -v listed {len(frames)} frames:\n{text}"
        for hex_id, data in frames:
            can_id = int(hex_id, 16)
            request = data == "" or data.startswith("R")
            if can_id >> 5 in NODES or (can_id == ADDRESS_REQUEST_ID and request):
                continue
            count += 1
    return count


def check_garbage_counted(run: DeviceRun) -> dict:
    """Every garbage frame where it belongs in the plant's CAN counters; returns them."""
    for code, text in run.devices[-len(GARBAGE) :]:
        assert code == 0, f"cangen failed:\n{text}"
    log = run.plant()
    assert log.final is not None, "the plant did not end cleanly (no hop-log footer)"
    can = log.final["can"]
    print(f"plant's CAN counters: {can}")
    samples = log.table("samples")
    # The plant still sampled after the last garbage frame was sent (the same CLOCK_MONOTONIC):
    # every frame reached its socket before it stopped.
    if samples:
        assert max(r["wake_ns"] for r in samples) > run.finite_end_ns, "lengthen the run"
    # A frame the plant did not classify was dropped by its socket while it was behind, or
    # still queued when it stopped (read then, logged, not classified).
    drops = can["socket_drops"] + can["unread_at_stop"]
    ext = can["ignored"].get("extended_id", 0)
    other = can["ignored"].get("other_node", 0)
    expected_other = other_node_frames(run)
    expected_ext = dict((n, k) for n, _, k in GARBAGE)["extended"]
    # counted at most once each, and all of them but those
    assert ext <= expected_ext <= ext + drops, (ext, expected_ext, drops)
    assert other <= expected_other <= other + drops, (other, expected_other, drops)
    rej = can["rejections"]
    # the random frames to the drives' ids add more of these: at least ours
    assert rej.get("wrong_dlc", 0) + drops >= SHORT_FRAMES, rej
    assert rej.get("non_finite", 0) + drops >= NAN_FRAMES, rej
    assert run.summary()["exit_codes"]["plant"] == 0, run.summary()["exit_codes"]
    run.judged()
    return can


def test_garbage_beside_a_c_device_is_counted_and_refused(tmp_path, spawn):
    binary = build_c_controller(tmp_path)
    # at 20 Hz a wheel, as in the C device test: the guest's plant reads little more
    device = [str(binary), "-i", CHANNEL, "-l", "0", "-r", "1", "-f", "20"]
    run = run_devices(
        spawn, tmp_path / "run", [device], duration=14.0, finite=cangen_argvs(),
        finite_after_connect=True,
    )  # fmt: skip
    assert "device connected after" in run.stderr, run.stderr
    can = check_garbage_counted(run)
    # The torques of 3.4e38 reached an armed drive and were clamped to its limit, as the
    # firmware clamps; what the plant applied stayed within (2).
    assert can["events"].get("torque_clamped", 0) >= 1, can["events"]
    torques_within_limits(run)
    dev_code, dev_out = run.devices[0]
    assert dev_code == 0, dev_out  # the device lived through the garbage too
    # The most hostile folder of these tests: hil report reads it too, on its own.
    rep = report(run.out)
    assert rep.returncode in (0, 1, 4), rep.stderr
    assert rep.returncode == run.code, (run.code, rep.returncode)  # one verdict, judged once
    extremes = run.plant().info["extremes"]
    print(f"garbage beside the C device: exit {run.code}, hil report exit {rep.returncode};")
    print(f"  {run.stdout.strip()}; the plant's extremes {extremes}")


def test_garbage_alone_is_counted_and_applies_nothing(tmp_path, spawn):
    """No device but cangen: every frame counted, the drives never armed, nothing applied,
    a folder with a FAIL verdict."""
    garbage = cangen_argvs()
    run = run_devices(spawn, tmp_path / "run", [], duration=8.0, wait_device=12.0, finite=garbage)
    can = check_garbage_counted(run)
    conn = run.device_json()
    if conn["connected_after_s"] is None:
        assert "no device connected within" in run.stderr, run.stderr
    # garbage never armed a drive (none asks 8 in its 4 bytes), so no torque acted
    assert {d["axis_state"] for d in can["drives"].values()} == {1}, can["drives"]
    samples = run.plant().table("samples")
    assert all(r["tau1"] == 0.0 and r["tau2"] == 0.0 for r in samples)
    torques_within_limits(run, need_samples=False)
    # nothing armed, nothing applied: a FAIL, never a PASS
    assert run.code == 1, (run.code, run.stdout, run.stderr)
    said = run.stdout + run.stderr
    # who let it in is the garbage's luck: an input-shaped frame in the window or none
    refusals = ("no device connected within", "never armed the drives", "sent no command")
    assert any(r in said for r in refusals), said
    print(f"garbage alone: exit {run.code}; connected: {conn['how']!r}; {run.stdout.strip()}")

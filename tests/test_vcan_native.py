"""python-can over a real SocketCAN vcan0: the check that the vcan lane itself works.

Marked ``vcan``: runs where vcan0 exists (natively, or inside the QEMU guest that
tests/test_vcan_lane.py boots); skipped elsewhere by tests/conftest.py.
"""

from __future__ import annotations

import random
import select
import subprocess
import time

import pytest

can = pytest.importorskip("can")

from tools.vcan_guest.can_echo import (  # noqa: E402
    REPLY_FLIP_EXT,
    REPLY_FLIP_STD,
    STOP_ID,
    reply_to,
)

pytestmark = [pytest.mark.vcan, pytest.mark.timeout(300)]

CHANNEL = "vcan0"
# Generous: under TCG emulation starting Python and importing python-can takes seconds.
START_TIMEOUT_S = 120.0
REPLY_TIMEOUT_S = 10.0


def _read_line(proc: subprocess.Popen, timeout: float) -> str:
    """One stdout line of ``proc`` within ``timeout`` seconds ('' on timeout or exit)."""
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    return proc.stdout.readline().decode().strip() if ready else ""


def _requests(seed: int, n: int) -> list[can.Message]:
    """Standard and extended ids and every DLC 0..8; ids never carry the reply bit."""
    rng = random.Random(seed)
    out = []
    for _ in range(n):
        extended = rng.random() < 0.3
        ident = rng.randrange(0, REPLY_FLIP_EXT) if extended else rng.randrange(1, REPLY_FLIP_STD)
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        out.append(can.Message(arbitration_id=ident, is_extended_id=extended, data=data))
    return out


def _next_reply(bus: can.BusABC) -> can.Message:
    deadline = time.monotonic() + REPLY_TIMEOUT_S
    while time.monotonic() < deadline:
        msg = bus.recv(timeout=max(0.0, deadline - time.monotonic()))
        if msg is not None and not msg.is_error_frame:
            return msg
    raise AssertionError(f"no reply on {CHANNEL} within {REPLY_TIMEOUT_S} s")


def _same(got: can.Message, want: can.Message) -> bool:
    return (
        got.arbitration_id == want.arbitration_id
        and got.is_extended_id == want.is_extended_id
        and bytes(got.data) == bytes(want.data)
        and got.dlc == want.dlc
    )


def test_echo_peer_answers_every_frame_in_order(spawn):
    echo = spawn.python(
        ["-m", "tools.vcan_guest.can_echo", "--channel", CHANNEL], stderr=subprocess.STDOUT
    )
    assert _read_line(echo, START_TIMEOUT_S) == "READY", "echo process did not bind vcan0"
    lockstep = _requests(seed=1, n=300)
    burst = _requests(seed=2, n=100)
    with can.Bus(interface="socketcan", channel=CHANNEL) as bus:
        for i, req in enumerate(lockstep):
            bus.send(req)
            got = _next_reply(bus)
            assert _same(got, reply_to(req)), f"lockstep frame {i}: sent {req}, got {got}"
        # Back to back without waiting: the kernel queues must keep every frame and the order.
        for req in burst:
            bus.send(req)
        for i, req in enumerate(burst):
            got = _next_reply(bus)
            assert _same(got, reply_to(req)), f"burst frame {i}: sent {req}, got {got}"
        bus.send(can.Message(arbitration_id=STOP_ID, is_extended_id=False))
    assert _read_line(echo, REPLY_TIMEOUT_S) == f"ECHOED {len(lockstep) + len(burst)}"
    assert echo.wait(timeout=REPLY_TIMEOUT_S) == 0


def test_kernel_filter_delivers_only_one_drive_node():
    """CANSimple ids are ``node_id << 5 | cmd_id``: a kernel filter on the node bits must pass
    that node's frames only (what each drive-side reader relies on)."""
    node = 3
    node_filter = [{"can_id": node << 5, "can_mask": 0x7E0, "extended": False}]
    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
        can.Bus(interface="socketcan", channel=CHANNEL, can_filters=node_filter) as rx,
    ):
        sent_to_node = []
        for n in range(6):
            for cmd in (0x01, 0x09, 0x0E):
                msg = can.Message(arbitration_id=n << 5 | cmd, is_extended_id=False, data=[n, cmd])
                tx.send(msg)
                if n == node:
                    sent_to_node.append(msg)
        sentinel = can.Message(arbitration_id=node << 5 | 0x1F, is_extended_id=False, data=[0xAA])
        tx.send(sentinel)
        received = []
        while True:
            msg = _next_reply(rx)
            received.append(msg)
            if msg.arbitration_id == sentinel.arbitration_id:
                break
    assert [m.arbitration_id for m in received] == [
        m.arbitration_id for m in [*sent_to_node, sentinel]
    ]
    assert all(_same(g, w) for g, w in zip(received, [*sent_to_node, sentinel], strict=True))

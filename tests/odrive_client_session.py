"""An ODrive client session against the bench's virtual drives, with a client nobody here wrote.

The client is the PyPI package ``odrive-can`` (2.1.0, class ``ODriveCAN``, a test dependency),
one instance per drive, each on its own python-can bus object (its reader thread consumes the
bus); a third, raw bus sends remote requests and bad frames and watches the estimates. Run as

    python -m tests.odrive_client_session --interface zenoh_can --channel hil0 \
        --endpoint tcp/127.0.0.1:7449 [--watchdog 0.3]

against ``hil drives`` on the same bus. Prints a transcript (lines starting ``>``) and, last,
one JSON line of results that tests/test_can_odrive_conformance.py checks.

odrive-can 2.1.0 quirk, worked around here: its one-slot response queue keeps a second frame
with the requested id (e.g. a cyclic encoder frame arriving with the RTR answer) for the next
request, so :func:`request` drains it first.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import struct
import sys
import time
from typing import Any

import can
from odrive_can import ODriveCAN

TRANSCRIPT: list[str] = []
T0 = time.monotonic()


def say(text: str) -> None:
    line = f"> [{time.monotonic() - T0:6.2f}s] {text}"
    TRANSCRIPT.append(line)
    print(line, flush=True)


def open_bus(a: argparse.Namespace) -> can.BusABC:
    kw: dict[str, Any] = {"interface": a.interface, "channel": a.channel}
    if a.interface == "zenoh_can" and a.endpoint:
        kw["endpoint"] = a.endpoint
    return can.Bus(**kw)


async def request(drv: ODriveCAN, name: str, timeout: float = 0.5) -> dict:
    while not drv._response_queue.empty():  # the client's stale second response (see above)
        drv._response_queue.get_nowait()
    return await drv._request(name, timeout)


def plain(d: dict) -> dict:
    return {k: (v.name if hasattr(v, "name") else v) for k, v in d.items()}


async def wait_state(drv: ODriveCAN, state: str, timeout: float = 2.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if drv._last_heartbeat is not None and drv.axis_state == state:
            return True
        await asyncio.sleep(0.02)
    return False


async def hold_torque(drives: dict[str, ODriveCAN], torques: dict[str, float], seconds: float):
    """Send the torques every 20 ms for ``seconds`` (a host's control loop)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for side, drv in drives.items():
            drv.set_input_torque(torques[side])
        await asyncio.sleep(0.02)


class EncoderWatch:
    """Every Get_Encoder_Estimates frame of one node, seen on the raw bus (with its time)."""

    def __init__(self, node: int) -> None:
        self.arb = node << 5 | 0x09
        self.frames: list[tuple[float, float, float]] = []

    def __call__(self, msg: can.Message) -> None:
        if msg.arbitration_id == self.arb and not msg.is_remote_frame and len(msg.data) == 8:
            pos, vel = struct.unpack("<ff", bytes(msg.data))
            self.frames.append((msg.timestamp, pos, vel))  # the bus' arrival time


def line_fit(points: list[tuple[float, float, float]]) -> tuple[float, float]:
    """Largest deviation of positions from a least-squares line over time, and of velocities
    from their mean."""
    n = len(points)
    ts = [p[0] for p in points]
    ps = [p[1] for p in points]
    tm, pm = sum(ts) / n, sum(ps) / n
    var = sum((t - tm) ** 2 for t in ts) or 1e-12
    slope = sum((t - tm) * (p - pm) for t, p in zip(ts, ps, strict=True)) / var
    pos_dev = max(abs(p - (pm + slope * (t - tm))) for t, p in zip(ts, ps, strict=True))
    vm = sum(p[2] for p in points) / n
    return pos_dev, max(abs(p[2] - vm) for p in points)


async def session(a: argparse.Namespace) -> dict[str, Any]:
    res: dict[str, Any] = {}
    right = ODriveCAN(a.node_right, open_bus(a))
    left = ODriveCAN(a.node_left, open_bus(a))
    raw = open_bus(a)
    watch = EncoderWatch(a.node_right)
    notifier = can.Notifier(raw, [watch])
    drives = {"right": right, "left": left}
    try:
        for d in drives.values():
            await asyncio.wait_for(d.start(), 10.0)
        res["first_heartbeat"] = {s: plain(d._last_heartbeat.data) for s, d in drives.items()}
        say(f"heartbeats: right {res['first_heartbeat']['right']}")

        res["version"] = plain(await request(right, "Get_Version"))
        say(f"Get_Version (RTR) -> {res['version']}")

        # --- arm in torque control ------------------------------------------------------
        for d in drives.values():
            d.clear_errors()
            d.set_controller_mode("TORQUE_CONTROL", "PASSTHROUGH")
            d.set_input_torque(0.0)
        for d in drives.values():
            await d.set_axis_state("CLOSED_LOOP_CONTROL")
        res["armed"] = {s: str(d.axis_state) for s, d in drives.items()}
        say(f"Clear_Errors, TORQUE_CONTROL/PASSTHROUGH, CLOSED_LOOP_CONTROL -> {res['armed']}")

        # --- torque moves the wheels the right way --------------------------------------
        p0 = plain(await request(right, "Get_Encoder_Estimates"))
        await hold_torque(drives, {"right": 0.02, "left": 0.02}, 0.5)
        res["forward"] = {
            s: plain(await request(d, "Get_Encoder_Estimates")) for s, d in drives.items()
        }
        res["forward"]["right_start"] = p0
        say(f"0.02 Nm on both for 0.5 s -> estimates {res['forward']}")
        res["torques"] = plain(await request(right, "Get_Torques"))
        res["iq"] = plain(await right.get_iq())
        res["powers"] = plain(await request(right, "Get_Powers"))
        res["bus"] = plain(await right.get_bus_voltage_current())
        res["error"] = plain(await request(right, "Get_Error"))
        res["temperature"] = plain(await request(right, "Get_Temperature"))
        say(f"Get_Torques {res['torques']}  Get_Iq {res['iq']}")
        say(f"Get_Powers {res['powers']}  Get_Bus_Voltage_Current {res['bus']}")
        say(f"Get_Error {res['error']}  Get_Temperature {res['temperature']}")

        # --- coasting: periodic and RTR estimates lie on one line ------------------------
        await hold_torque(drives, {"right": 0.0, "left": 0.0}, 0.05)
        watch.frames.clear()
        rtr = 0
        for _ in range(10):
            raw.send(
                can.Message(arbitration_id=watch.arb, is_remote_frame=True, is_extended_id=False)
            )
            rtr += 1
            for d in drives.values():
                d.set_input_torque(0.0)  # a host's loop goes on (and feeds the watchdog)
            await asyncio.sleep(0.04)
        got = list(watch.frames)
        span = got[-1][0] - got[0][0] if len(got) > 1 else 0.0
        pos_dev, vel_dev = line_fit(got) if len(got) > 2 else (math.inf, math.inf)
        res["coast"] = {
            "frames": len(got),
            "rtr_sent": rtr,
            "span_s": span,
            "pos_dev": pos_dev,
            "vel_dev": vel_dev,
            # the positions' span: the drive's own time, at its velocity
            "pos_span": max(p[1] for p in got) - min(p[1] for p in got) if got else 0.0,
            "vel": got[-1][2] if got else None,
            "pos": got[-1][1] if got else None,
        }
        say(
            f"coasting, 10 RTR among the cyclic frames: {len(got)} frames in {span:.3f} s, "
            f"largest deviation from one line {pos_dev:.2e} rev, velocity spread {vel_dev:.2e}"
        )

        # --- turn: right forward, left back ------------------------------------------------
        await hold_torque(drives, {"right": 0.02, "left": -0.02}, 0.3)
        await hold_torque(drives, {"right": 0.0, "left": 0.0}, 0.05)
        res["turn"] = {
            s: plain(await request(d, "Get_Encoder_Estimates")) for s, d in drives.items()
        }
        say(f"turn (+0.02, -0.02 Nm) -> {res['turn']}")

        # --- limits clamp the torque ----------------------------------------------------------
        right.set_limits(200.0, 1.0)  # 1 A x 0.04 Nm/A = 0.04 Nm
        right.set_input_torque(0.3)
        await asyncio.sleep(0.05)
        res["limited_torques"] = plain(await request(right, "Get_Torques"))
        say(f"Set_Limits(200 rev/s, 1 A), torque 0.3 -> Get_Torques {res['limited_torques']}")
        right.set_limits(200.0, 100.0)
        for d in drives.values():
            d.set_input_torque(0.0)

        # --- velocity control through the drive's loop -------------------------------------
        for d in drives.values():
            d.set_controller_mode("VELOCITY_CONTROL", "PASSTHROUGH")
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            for d in drives.values():
                d.set_input_vel(5.0)
            await asyncio.sleep(0.05)
        res["velocity"] = {
            s: plain(await request(d, "Get_Encoder_Estimates")) for s, d in drives.items()
        }
        say(f"VELOCITY_CONTROL, Set_Input_Vel 5 rev/s for 1.5 s -> {res['velocity']}")
        t_end = time.monotonic() + 0.6  # stop (the loop's integrator settles)
        while time.monotonic() < t_end:
            for d in drives.values():
                d.set_input_vel(0.0)
            await asyncio.sleep(0.05)

        # --- absolute position, then position control ----------------------------------------
        right.set_linear_count(100.0)  # odrive-can's name for Set_Absolute_Position
        await asyncio.sleep(0.05)
        res["absolute"] = plain(await request(right, "Get_Encoder_Estimates"))
        say(f"Set_Absolute_Position 100 -> {res['absolute']}")
        for d in drives.values():
            d.set_controller_mode("POSITION_CONTROL", "PASSTHROUGH")
        target = res["absolute"]["Pos_Estimate"] + 2.0
        t_end = time.monotonic() + 1.5
        while time.monotonic() < t_end:
            right.set_input_pos(target)
            left.set_input_torque(0.0)  # keeps its watchdog fed; holds its position
            await asyncio.sleep(0.05)
        res["position"] = {
            "target": target,
            **plain(await request(right, "Get_Encoder_Estimates")),
        }
        say(f"POSITION_CONTROL to {target:.3f} rev -> {res['position']}")

        # --- estop and recovery ----------------------------------------------------------------
        for d in drives.values():
            d._send_message("Estop")
        estopped = all([await wait_state(d, "IDLE") for d in drives.values()])
        await right.wait_for_heartbeat()
        res["estop"] = {
            "idle": estopped,
            "heartbeat": plain(right._last_heartbeat.data),
            "error": plain(await request(right, "Get_Error")),
        }
        try:
            right.check_errors()
            res["estop"]["check_errors"] = "no error"
        except Exception as exc:  # odrive_can.odrive.DriveError
            res["estop"]["check_errors"] = f"{type(exc).__name__}: {exc}"
        say(f"Estop -> {res['estop']}")
        right.set_axis_state_no_wait("CLOSED_LOOP_CONTROL")
        await asyncio.sleep(0.25)
        res["estop"]["rearm_refused"] = str(right.axis_state)
        for d in drives.values():
            d.clear_errors()
            d.set_controller_mode("TORQUE_CONTROL", "PASSTHROUGH")
        # The right drive's last command (its watchdog's last feed) leaves after this stamp.
        t_fed = time.monotonic()
        for d in drives.values():
            await d.set_axis_state("CLOSED_LOOP_CONTROL")
        res["recovered"] = {s: str(d.axis_state) for s, d in drives.items()}
        say(
            f"closed loop before Clear_Errors -> {res['estop']['rearm_refused']}; "
            f"after Clear_Errors -> {res['recovered']}"
        )

        # --- watchdog expiry: a silent host ----------------------------------------------------
        if a.watchdog > 0:
            t_silent = time.monotonic()
            expired = await wait_state(right, "IDLE", timeout=a.watchdog + 1.0)
            res["watchdog"] = {
                "idle": expired,
                "after_s": time.monotonic() - t_silent,
                "since_feed_s": time.monotonic() - t_fed,
                "heartbeat": plain(right._last_heartbeat.data),
                "error": plain(await request(right, "Get_Error")),
            }
            say(f"host silent -> {res['watchdog']}")
            for d in drives.values():
                d.clear_errors()

        for d in drives.values():
            d.set_axis_state_no_wait("IDLE")
        res["idle_at_end"] = all([await wait_state(d, "IDLE") for d in drives.values()])
        say(f"IDLE -> {res['idle_at_end']}")
    finally:
        notifier.stop()
        for d in drives.values():
            d._running = False
        for d in drives.values():
            if d._recieve_thread is not None:
                d._recieve_thread.join(timeout=2.0)
            d._bus.shutdown()
    try:
        # Bad frames from a tool, once the clients are gone (odrive-can's reader task dies on
        # a frame shorter than its DBC says): the drives count them and apply nothing.
        arb = a.node_right << 5 | 0x0E
        for data in (struct.pack("<f", math.nan), b"\x00\x00\xc0", struct.pack("<ff", 9.0, 0)):
            raw.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))
        res["bad_frames_sent"] = 3
        say("sent Set_Input_Torque NaN, a 3-byte Set_Input_Torque and 9 Nm to an idle drive")
    finally:
        raw.shutdown()
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--interface", default="zenoh_can")
    p.add_argument("--channel", default="hil0")
    p.add_argument("--endpoint", default=None)
    p.add_argument("--node-right", type=int, default=1)
    p.add_argument("--node-left", type=int, default=0)
    p.add_argument("--watchdog", type=float, default=0.0, help="the drives' watchdog timeout")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    res = asyncio.run(session(a))
    res["transcript"] = TRANSCRIPT
    print(json.dumps(res, default=str), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

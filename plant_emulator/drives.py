"""The plant with its two virtual ODrives on any python-can bus, free running: ``python -m
plant_emulator.drives SETTINGS.json`` from a resolved settings file, or ``hil drives SCENARIO``
(the front that resolves a scenario first).

No start gate and no controller of the bench: the robot of the settings (``hil drives``'s
default: ``hil run``'s scenario, the paper's set-up) starts integrating at once, at rest at its
initial pose, and moves when a client (an ODrive script, a user's controller, ``odrive-can``)
commands the drives over CAN. Until SIGINT/SIGTERM, then it prints a summary and exits within a
second.

Threads: the bus edge (:class:`plant_emulator.can_drives.CanDrives`) receives and answers at
once, advancing the plant to each frame's arrival first, and sends heartbeats and encoder
estimates at their rates; the main loop steps the plant and the drives' controllers
(velocity/position loops, watchdog) at ``control_rate``, optionally publishes State (and Status
with the drives' counters) on Zenoh, and prints a status line every ``status_period``.
"""

from __future__ import annotations

import contextlib
import gc
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plant_emulator.can_drives import CanDrives
from plant_emulator.drive_plant import DrivePlant, run_drive_config
from plant_emulator.odrive import VirtualDrivePair
from plant_emulator.service import build_plant
from protocol import keys
from protocol.can.codec import AxisState, Cmd, Frame, frame_for_other_node
from protocol.settings import RunSettings, period_ns, period_s

# The drives' settings a summary records (docs/can.md, "Defaults").
SUMMARY_CONFIG = (
    "vel_limit",
    "vel_limit_tolerance",
    "enable_torque_mode_vel_limit",
    "enable_overspeed_error",
    "torque_limit",
    "current_limit",
    "torque_constant",
    "vel_gain",
    "watchdog_timeout",
)
STATE_NAMES = {
    AxisState.IDLE: "IDLE",
    AxisState.CLOSED_LOOP_CONTROL: "CLOSED_LOOP",
    AxisState.UNDEFINED: "UNDEFINED",
}


@dataclass
class DrivesOptions:
    """How the drives run (``hil drives --help``); the robot, its limits and the bus are the
    resolved settings' (:class:`protocol.settings.RunSettings`)."""

    control_rate: float = 1000.0  # Hz: plant steps and drive controller steps
    msg_rates_ms: dict[int, float] = field(
        default_factory=lambda: {Cmd.HEARTBEAT: 100.0, Cmd.GET_ENCODER_ESTIMATES: 10.0}
    )
    state_rate: float = 0.0  # Hz of State on Zenoh (0: no Zenoh at all)
    zenoh_endpoint: str = "tcp/127.0.0.1:7447"
    status_period: float = 1.0  # s between status lines (0: none)
    duration: float | None = None  # s, then exit as on SIGINT (None: until a signal)
    out: Path | None = None  # where summary.json goes (None: stdout only)


class DrivesRunner:
    """The plant and its two drives on one bus (built from :class:`DrivesOptions`)."""

    def __init__(self, opts: DrivesOptions, settings: RunSettings, bus: Any = None) -> None:
        from protocol.can.bus_factory import CanSettings, open_bus
        from protocol.can.wheel_mapping import RobotGeometry

        self.opts = opts
        self.settings = settings
        can_table = dict(settings.can)
        if can_table.get("interface") == "virtual" and bus is None:
            can_table.update(interface="zenoh_can", channel="hil0")  # in-process only
        self.can_settings = cs = CanSettings.from_table(can_table)
        watchdog = cs.watchdog_timeout
        if not (math.isfinite(watchdog) and watchdog >= 0.0):
            raise ValueError(f"watchdog timeout must be >= 0 s, got {watchdog}")
        if not (math.isfinite(opts.control_rate) and 1.0 <= opts.control_rate <= 20_000.0):
            raise ValueError(f"control rate must be in 1..20000 Hz, got {opts.control_rate}")
        self.geometry = RobotGeometry(**settings.robot)
        # At rest at the initial pose: the robot moves when torque arrives.
        self.core, _ = build_plant(settings, at_rest=True)
        limits = self.core.limits
        # The firmware's defaults with what the bench sets from the scenario (docs/can.md)
        self.drive_config = run_drive_config(settings, opts.msg_rates_ms)
        self.pair = VirtualDrivePair(cs.node_right, cs.node_left, config=self.drive_config)
        self.t0_ns = time.monotonic_ns()
        self.drive_plant = DrivePlant(
            self.pair, self.geometry, limits, 0.0, self.core.state, self.t0_ns / 1e9
        )
        extra = {}
        if cs.interface == "zenoh_can" and settings.can_endpoint:
            extra["endpoint"] = settings.can_endpoint
        self.bus = bus if bus is not None else open_bus(cs, **extra)
        # Requests and cyclic frames are answered from the drives' feedback (at most one
        # control period old, extrapolated at its velocity): no plant step on that path.
        self.can = CanDrives(self.bus, self.pair, on_frame=self._on_frame, immediate=True)
        self.robot_id = settings.robot_id
        self.session: Any = None
        self._pub_state: Any = None
        self._pub_status: Any = None
        self.tap: Any = None
        self._state_seq = 0
        self._status_seq = 0

    # --- the plant, under the edge's lock ----------------------------------------------------
    def _advance(self, now_ns: int) -> float:
        """Integrate the plant up to ``now_ns``; returns the drives' time of the plant's time."""
        self.core.advance_to((now_ns - self.t0_ns) / 1e9)
        return self.t0_ns / 1e9 + self.core.t

    def _on_frame(self, recv_ns: int, frame: Frame) -> list[Frame]:
        """A frame lands at its arrival: the plant runs up to it, then the drives take it.
        Another node's frame changes nothing here: counted (ignored) without a plant step,
        as every frame of a busy bus would otherwise cost one."""
        if frame_for_other_node(frame, self.pair.nodes):
            return self.pair.receive(self.t0_ns / 1e9 + self.core.t, frame)
        now = self._advance(recv_ns)
        self.drive_plant.feedback(now, self.core.t, self.core.state)
        answers = self.pair.receive(now, frame)
        self.core.hold(*self.drive_plant.torques())
        return answers

    def step(self, now_ns: int) -> None:
        with self.can.lock:
            now = self._advance(now_ns)
            self.drive_plant.update(now, self.core.t, self.core.state)
            self.core.hold(*self.drive_plant.torques())

    # --- Zenoh -------------------------------------------------------------------------------
    def open_zenoh(self) -> None:
        from runtime.tap import Tap
        from runtime.zsession import open_session, publisher

        self.session = open_session(self.opts.zenoh_endpoint)
        self._pub_state = publisher(self.session, keys.state_key(self.robot_id))
        self._pub_status = publisher(self.session, keys.status_key(self.robot_id))
        self.tap = Tap(self.session, self.robot_id, "drives")  # what a live view reads

    def publish_state(self, sample_ns: int) -> None:
        from protocol.messages import State, encode

        with self.can.lock:
            s = self.core.state
        msg = State(
            self.robot_id,
            self._state_seq,
            sample_ns,
            time.monotonic_ns(),
            float(s.x),
            float(s.y),
            float(s.theta),
            float(s.v),
            float(s.omega),
        )
        self._state_seq += 1
        with contextlib.suppress(ValueError):  # a state beyond the message's ranges
            payload = encode(msg)
            self._pub_state.put(payload)
            self.tap.sent(keys.STATE, msg.send_time_ns, payload)

    def publish_status(self, state: str) -> None:
        from protocol.messages import Status, encode

        counters = self.can.status_counters()
        counters["states"] = self._state_seq
        msg = Status(
            self.robot_id, self._status_seq, time.monotonic_ns(), "drives", state, 0, counters
        )
        self._status_seq += 1
        with contextlib.suppress(Exception):
            self._pub_status.put(encode(msg))

    # --- reports -----------------------------------------------------------------------------
    def status_line(self, elapsed: float, rates: tuple[float, float]) -> str:
        with self.can.lock:
            c = self.pair.counters()
            s = self.core.state
        parts = [f"drives t={elapsed:7.1f}s"]
        for side, node in (("R", self.pair.node_right), ("L", self.pair.node_left)):
            d = c["drives"][str(node)]
            name = STATE_NAMES.get(d["axis_state"], str(d["axis_state"]))
            parts.append(
                f"{side} n{node} {name} err=0x{d['axis_error']:x} q={d['torque_nm']:+.3f}Nm "
                f"v={d['vel_rev_s']:+.2f}rev/s p={d['pos_rev']:+.2f}rev"
            )
        rej = c["rejections"]
        kinds = ", ".join(f"{k} {n}" for k, n in rej.items())
        ign = sum(c["ignored"].values())
        parts.append(
            f"rx {rates[0]:.0f}/s ({self.can.frames_in}) tx {rates[1]:.0f}/s "
            f"({self.can.frames_out}) req {self.can.requests} "
            f"rej {sum(rej.values())}{f' ({kinds})' if kinds else ''} other {ign} "
            f"own {self.can.own_frames}"
        )
        parts.append(f"robot x={s.x:+.3f} y={s.y:+.3f} v={s.v:+.3f}")
        parts.append(self.watchdog_words())
        return " | ".join(parts)

    def watchdog_words(self) -> str:
        """The drives' watchdog, as the status lines say it."""
        timeout = self.can_settings.watchdog_timeout
        return f"watchdog {timeout:g}s" if timeout > 0 else "watchdog off"

    def config_words(self) -> str:
        """What the bench set on the drives, as the start line says it."""
        c = self.drive_config
        return (
            f"hil drives: the firmware's defaults (docs/can.md) but vel_limit {c.vel_limit:.2f} "
            f"rev/s (the corner of (2), |v| = phi1 with |omega| = phi2, plus the torque ramp; "
            f"in torque control no wheel is driven past it, beyond {c.vel_limit_tolerance:g}x "
            f"it a drive trips its overspeed error), torque limit {c.max_torque:.4f} Nm "
            f"(varpi1, varpi2 of (2)), current limit {c.current_limit:.2f} A"
        )

    def summary(self, elapsed: float, stopped_by: str) -> dict[str, Any]:
        e = self.core.extremes
        with self.can.lock:
            s = self.core.state
        return {
            "kind": "drives",
            "stopped_by": stopped_by,
            "elapsed_s": elapsed,
            "interface": self.can_settings.interface,
            "channel": self.can_settings.channel,
            "nodes": {"right": self.pair.node_right, "left": self.pair.node_left},
            # the configuration the drives started with (the firmware's with the bench's)
            "drive_config": {k: getattr(self.drive_config, k) for k in SUMMARY_CONFIG},
            "can": self.can.counters(),
            "robot": {
                "final": {"x": s.x, "y": s.y, "theta": s.theta, "v": s.v, "omega": s.omega},
                "max_abs_v": e.max_abs_v,
                "max_abs_omega": e.max_abs_omega,
                "violations": {
                    "v": int(e.violations_v),
                    "omega": int(e.violations_omega),
                    "tau1": int(e.violations_tau1),
                    "tau2": int(e.violations_tau2),
                },
            },
        }

    # --- the loop ----------------------------------------------------------------------------
    def run(self, stop: Any) -> dict[str, Any]:
        from runtime.realtime import DeadlineClock, raise_threads, setup_scheduling

        opts = self.opts
        self.can.start()
        if opts.state_rate > 0:
            self.open_zenoh()
        scheduling = self.settings.scheduling
        # Threads exist now, so SCHED_FIFO reaches the bus edge's too. The
        # collector stays on (the process runs for hours); what exists now is frozen once.
        sched = setup_scheduling(scheduling, freeze_gc=False, idle=self.settings.idle)
        if sched.policy == "SCHED_FIFO":
            # The bus edge at the loop's own priority, above Zenoh's helper threads: a request
            # is answered and a cyclic frame sent as promptly as a bare python-can peer does.
            raise_threads(self.can.native_ids(), sched.priority)
        gc.collect()
        gc.freeze()
        period = period_ns(period_s(opts.control_rate))
        state_every = (
            max(1, round(opts.control_rate / opts.state_rate)) if opts.state_rate > 0 else 0
        )
        status_ns = int(opts.status_period * 1e9) if opts.status_period > 0 else 0
        cs = self.can_settings
        print(
            f"hil drives: right node {self.pair.node_right}, left node {self.pair.node_left} on "
            f"{cs.interface} {cs.channel}; plant and drives at {opts.control_rate:g} Hz, "
            f"{sched.policy}; {self.watchdog_words()} (a drive that gets no command for that long "
            "disarms: Clear_Errors, then Set_Axis_State re-arms it); Ctrl-C to stop",
            flush=True,
        )
        print(self.config_words(), flush=True)
        start_ns = time.monotonic_ns()
        clock = DeadlineClock(period, start_ns)
        next_status = start_ns + status_ns
        last = (start_ns, self.can.frames_in, self.can.frames_out)
        end_ns = start_ns + int(opts.duration * 1e9) if opts.duration else None
        stopped_by = "signal"
        while not stop:
            tick = clock.next()
            if end_ns is not None and tick.deadline_ns >= end_ns:
                stopped_by = "duration"
                break
            self.step(tick.deadline_ns)
            if state_every and tick.k % state_every == 0:
                self.publish_state(tick.deadline_ns)
                self.tap.flush_if_due(tick.wake_ns)
            if status_ns and tick.wake_ns >= next_status:
                while next_status <= tick.wake_ns:
                    next_status += status_ns
                dt = max(1e-9, (tick.wake_ns - last[0]) / 1e9)
                rates = ((self.can.frames_in - last[1]) / dt, (self.can.frames_out - last[2]) / dt)
                last = (tick.wake_ns, self.can.frames_in, self.can.frames_out)
                print(self.status_line((tick.wake_ns - start_ns) / 1e9, rates), flush=True)
                if self.session is not None:
                    self.publish_status("running")
        elapsed = (time.monotonic_ns() - start_ns) / 1e9
        if self.session is not None:
            self.tap.close()
            self.publish_status("stopped")
        summary = self.summary(elapsed, stopped_by)
        summary["scheduling"] = sched.as_dict()
        summary["deadline_misses"] = clock.misses
        return summary

    def close(self) -> None:
        self.can.close()
        if self.session is not None:
            with contextlib.suppress(Exception):
                self.session.close()


def run_drives(opts: DrivesOptions, settings: RunSettings) -> int:
    """Build, run until a signal (or ``duration``), print and write the summary; exit code."""
    from runtime.signals import stop_on_signals

    with stop_on_signals() as stop:
        runner = DrivesRunner(opts, settings)
        try:
            summary = runner.run(stop)
        finally:
            runner.close()
    text = json.dumps({"summary": summary}, default=float)
    print(text, flush=True)
    if opts.out is not None:
        opts.out.mkdir(parents=True, exist_ok=True)
        (opts.out / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m plant_emulator.drives SETTINGS.json [--duration S] [--out DIR] ...``: the
    drives from a resolved settings file alone (``hil drives`` is the front with a scenario)."""
    import argparse

    import can

    from protocol.errors import BadInputError

    p = argparse.ArgumentParser(prog="python -m plant_emulator.drives", description=main.__doc__)
    p.add_argument("settings", help="resolved settings (hil emulator SCENARIO --write-settings F)")
    p.add_argument("--control-rate", type=float, default=DrivesOptions.control_rate)
    p.add_argument("--state-rate", type=float, default=DrivesOptions.state_rate)
    p.add_argument("--endpoint", default=DrivesOptions.zenoh_endpoint)
    p.add_argument("--status-period", type=float, default=DrivesOptions.status_period)
    p.add_argument("--duration", type=float, default=None)
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    opts = DrivesOptions(
        control_rate=a.control_rate,
        state_rate=a.state_rate,
        zenoh_endpoint=a.endpoint,
        status_period=a.status_period,
        duration=a.duration,
        out=a.out,
    )
    try:
        settings = RunSettings.load(a.settings)
        settings.validate()
        return run_drives(opts, settings)
    except (BadInputError, ValueError, OSError, can.CanError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

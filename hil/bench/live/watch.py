"""The live view's own process: ``python -m hil.bench.live SETTINGS.json... --port P [--host H]
...`` (docs/live.md: its channels, and why it runs apart from the loop's processes).

It subscribes to each robot's keys ``hil/<id>/**`` on that robot's Zenoh endpoint (one session
per endpoint) and, for one robot, listens to its CAN bus (both read-only), and serves
:class:`LiveView` (every channel JSON with its schema from :mod:`hil.schemas`) until SIGINT or
SIGTERM, then closes it (every client sees the close). It prints ``live: ws://HOST:PORT`` on
stdout once the server listens. A message's log time is the sender's stamp where it has one
(State sample time, command send time): one clock, the host's ``CLOCK_MONOTONIC``.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import os
import sys
import time
import tomllib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import can
import foxglove

from controller_service.certificate import critical_age
from controller_service.references import build_reference
from hil import schemas
from hil.bench.live.timing import Bounds, LiveTiming
from hil.bench.recorder import can_frame_record, to_jsonable
from hil.folder.scenario_view import bound_inputs
from hil.observe import InTimeOrder, TapReader
from protocol.keys import observed_keys
from protocol.messages import DecodeError, State, Status, Telemetry, TorqueCommand, decode
from protocol.settings import RunSettings
from runtime.signals import stop_on_signals
from runtime.zsession import open_session, payload_bytes

QUEUE_MAX = 200_000  # messages; past it the oldest are dropped (a live view may skip)
NICENESS = 10
ReferenceFn = Callable[[float], tuple[float, float, float]]  # t (s) -> (x, y, theta)


class LiveView:
    """Publishes decoded messages on a Foxglove WebSocket server (started here)."""

    def __init__(
        self,
        robot_ids: Sequence[str],
        bounds: Bounds,
        host: str = "127.0.0.1",
        port: int = 8765,
        reference: ReferenceFn | None = None,
        name: str = "hil-smc-bench",
    ) -> None:
        # One timing per robot (a fleet's robots each have their own deadlines and epoch).
        self.timings = {r: LiveTiming(bounds) for r in robot_ids}
        self.reference = reference
        self.epochs: dict[str, int] = {}
        self.context = foxglove.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        self.port = int(self.server.port)
        for robot in self.timings:
            for suffix in ("state", "cmd/torque", "telemetry", "status", schemas.POSE,
                           schemas.TF, schemas.REFERENCE, schemas.TIMING):  # fmt: skip
                self.channel(f"hil/{robot}/{suffix}")  # advertised from the start

    def channel(self, topic: str) -> Any:
        if topic not in self._channels:
            doc = schemas.schema_for_topic(topic)
            name, data = schemas.schema_name(topic, doc), json.dumps(doc).encode()
            schema = foxglove.Schema(name=name, encoding="jsonschema", data=data)
            self._channels[topic] = foxglove.Channel(
                topic, schema=schema, message_encoding="json", context=self.context
            )
        return self._channels[topic]

    def _log(self, topic: str, data: schemas.Json, log_time: int) -> None:
        ch = self.channel(topic)
        if ch.has_sinks():  # nobody subscribed: no JSON to build
            ch.log(data, log_time=int(log_time))

    def on_message(self, topic: str, msg: Any, recv_ns: int) -> None:
        """One decoded message received on ``topic`` (counted if its robot is the view's)."""
        robot = getattr(msg, "robot_id", "")
        timing = self.timings.get(robot)
        if isinstance(msg, State):
            if timing is not None:
                timing.on_state(msg, recv_ns)
            self._log(topic, _mirror(msg), msg.sample_time_ns)
            self._pose(topic.rsplit("/", 1)[0], msg)
        elif isinstance(msg, TorqueCommand):
            if timing is not None:
                timing.on_command(msg, recv_ns)
            self._log(topic, _mirror(msg), msg.send_time_ns)
        elif isinstance(msg, Status):
            if timing is not None:
                timing.on_status(msg)
            if robot not in self.epochs and int(msg.counters.get("epoch_ns", 0)) > 0:
                self.epochs[robot] = int(msg.counters["epoch_ns"])
            self._log(topic, _mirror(msg), msg.time_ns)
        elif isinstance(msg, Telemetry):
            self._log(topic, _mirror(msg), msg.time_ns)

    def _pose(self, base: str, st: State) -> None:
        t = st.sample_time_ns
        self._log(f"{base}/{schemas.POSE}", schemas.pose_in_frame(t, st.x, st.y, st.theta), t)
        tf = schemas.frame_transform(t, st.robot_id, st.x, st.y, st.theta)
        self._log(f"{base}/{schemas.TF}", tf, t)
        epoch = self.epochs.get(st.robot_id)
        if self.reference is not None and epoch is not None:
            x, y, th = self.reference((t - epoch) / 1e9)
            self._log(f"{base}/{schemas.REFERENCE}", schemas.pose_in_frame(t, x, y, th), t)

    def on_can(self, channel: str, frame: schemas.Json, recv_ns: int) -> None:
        """One CAN frame as the recorder's JSON (:func:`can_frame_record`)."""
        self._log(f"can/{channel}", frame, recv_ns)

    def tick(self, backlog: int) -> None:
        """Publish each robot's timing figures (call once a second)."""
        now = time.monotonic_ns()
        for robot, timing in self.timings.items():
            self._log(f"hil/{robot}/{schemas.TIMING}", timing.snapshot(now, backlog), now)

    def close(self) -> None:
        self.server.stop()


def _mirror(msg: Any) -> schemas.Json:
    return {**to_jsonable(msg), "type": type(msg).__name__}


def bounds_of(settings: RunSettings, resolved: Path | None) -> Bounds:
    """D* from the resolved scenario as the run's summary computes it (None: no certificate),
    Ts, the limits (2), the plant's sample period and the trigger from the settings."""
    d_star = None
    if resolved is not None and resolved.is_file():
        try:
            b = bound_inputs(tomllib.loads(resolved.read_text()))
            if b is not None:
                d_star = critical_age(b.params, b.context, b.boundary_layer, v0=b.v0, w0=b.w0)
        except Exception as exc:  # a design the certificate refuses: no D*, still a view
            print(f"live: no D* ({exc})", file=sys.stderr)
    lim = settings.limits
    periodic = settings.trigger == "periodic" and not settings.lockstep
    return Bounds(
        d_star, float(settings.ts), float(lim["phi1"]), float(lim["phi2"]),
        float(settings.sensor_ts), periodic,
    )  # fmt: skip


def reference_of(settings: RunSettings) -> Any:
    """t -> (xd, yd, thetad) of the run's reference (None when it cannot be built)."""
    try:
        ref = build_reference(settings.reference, Path(settings.base_dir))
    except Exception:
        return None

    def pose(t: float) -> tuple[float, float, float]:
        s = ref.sample(max(0.0, t))
        return float(s.xd), float(s.yd), float(s.thetad)

    return pose


def _subscribe(endpoint: str, robots: list[str], mode: str, q: collections.deque) -> list[Any]:
    """One session on ``endpoint`` subscribed to each of ``robots``' keys; what to close."""
    try:
        session = open_session(endpoint, mode=mode, credentials=None)
    except Exception as exc:  # hil drives without a Zenoh peer: the view shows the CAN side
        print(f"live: Zenoh messages of {', '.join(robots)} not shown: {exc}", file=sys.stderr)
        return []
    subs = [
        session.declare_subscriber(
            key, lambda s: q.append((str(s.key_expr), time.monotonic_ns(), payload_bytes(s)))
        )
        for robot in robots
        for key in observed_keys(robot)  # the taps, never the loop's own keys
    ]
    return [*reversed(subs), session]


def _open_inputs(runs: list[RunSettings], zenoh_mode: str, q: collections.deque) -> list[Any]:
    """The Zenoh subscriptions (each robot's keys on its own endpoint, once) and, for one
    robot, the CAN listener, feeding ``q``; what to close, in order."""
    by_endpoint: dict[str, list[str]] = {}
    for s in runs:
        by_endpoint.setdefault(s.zenoh_endpoint, []).append(s.robot_id)
    opened: list[Any] = []
    for endpoint, robots in by_endpoint.items():
        opened[:0] = _subscribe(endpoint, robots, zenoh_mode, q)
    if len(runs) > 1:  # a fleet runs without CAN
        return opened
    settings = runs[0]
    settings.can_live = True
    try:
        bus = settings.open_can_bus()
    except Exception as exc:  # the view still shows the Zenoh side
        print(f"live: CAN frames not shown: {exc}", file=sys.stderr)
        return opened
    if bus is not None:
        channel = str(settings.can.get("channel", "can"))
        notifier = can.Notifier(
            bus, [lambda m: q.append((f"can/{channel}", time.monotonic_ns(), m))], timeout=0.1
        )
        opened[:0] = [notifier, bus]
    return opened


def _close(opened: list[Any]) -> None:
    for thing in opened:
        with contextlib.suppress(Exception):  # closing what is already gone is fine here
            for name in ("undeclare", "stop", "shutdown", "close"):
                if hasattr(thing, name):
                    getattr(thing, name)()
                    break


def _drain(
    view: Any, q: collections.deque, taps: TapReader, order: InTimeOrder, now_ns: int | None
) -> int:
    """Feed the view what arrived, the services' messages in their time order (``now_ns``:
    those at least the hold old; None: all); the number of inputs taken."""
    n = 0
    while q:
        topic, t, payload = q.popleft()
        n += 1
        if topic.startswith("can/"):
            view.on_can(topic[4:], can_frame_record(payload), t)
            continue
        for m in taps.read(topic, t, payload):
            if not m.rejected:  # the recording keeps refused payloads; the view shows messages
                order.push(m)
    for m in order.ready(now_ns):
        with contextlib.suppress(DecodeError):
            view.on_message(m.topic, decode(m.payload), m.log_time_ns)
    return n


def serve(args: argparse.Namespace) -> int:
    """Serve until a signal; the exit code."""
    # Below the run's processes on the CPU: when the view and a service want the same core,
    # the service gets it (the view only falls behind, which its timing message shows).
    os.nice(NICENESS)
    runs = [RunSettings.load(path) for path in args.settings]
    settings = runs[0]  # a fleet's robots share the scenario: its bounds and reference
    bounds = bounds_of(settings, args.resolved)
    reference = None if args.no_reference else reference_of(settings)
    q: collections.deque = collections.deque(maxlen=QUEUE_MAX)
    # On the run's clock where the services share this host's; a lab's hosts do not.
    taps = TapReader(same_clock=not args.other_clocks)
    order = InTimeOrder()
    with stop_on_signals() as stop:
        view = LiveView([s.robot_id for s in runs], bounds, args.host, args.port, reference)
        opened: list[Any] = []
        try:
            opened = _open_inputs(runs, args.zenoh_mode, q)
            print(f"live: ws://{args.host}:{view.port}", flush=True)
            next_tick = time.monotonic() + 1.0
            while not stop:
                if not _drain(view, q, taps, order, time.monotonic_ns()):
                    time.sleep(0.005)
                if time.monotonic() >= next_tick:
                    view.tick(backlog=len(q))
                    next_tick += 1.0
        finally:
            _close(opened)
            view.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m hil.bench.live", description=__doc__)
    p.add_argument("settings", type=Path, nargs="+",
                   help="the run's run_settings.json (a fleet: each robot's)")  # fmt: skip
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8765)
    p.add_argument("--resolved", type=Path, default=None, help="scenario.resolved.toml: D*")
    p.add_argument("--zenoh-mode", default="client", choices=("client", "peer"))
    p.add_argument("--no-reference", action="store_true", help="no reference pose (drives)")
    p.add_argument("--other-clocks", action="store_true",
                   help="the services run on a lab's hosts: their stamps are not on this "
                   "host's clock")  # fmt: skip
    return serve(p.parse_args(argv))

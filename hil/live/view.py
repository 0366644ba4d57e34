"""The live view's Foxglove WebSocket server and what it publishes (foxglove-sdk).

Channels (JSON, each with its schema from :mod:`hil.schemas`, the recording's own):

- ``hil/<id>/state``, ``.../cmd/torque``, ``.../telemetry``, ``.../status``: the protocol's
  messages as the recording mirrors them;
- ``hil/<id>/pose`` (``foxglove.PoseInFrame``), ``hil/<id>/tf`` (``foxglove.FrameTransform``
  world -> <id>) and ``hil/<id>/reference`` (``foxglove.PoseInFrame`` of the reference at the
  State's sample time, once the run's epoch is known) for the 3D panel;
- ``can/<channel>``: the drives' frames, decoded as the recording decodes them;
- ``hil/<id>/live/timing`` (``hil.LiveTiming``): :mod:`hil.live.timing`'s figures once a second.

Log time of every message: the sender's stamp where it has one (State sample time, command send
time), so Foxglove's plots share one clock (the host's ``CLOCK_MONOTONIC``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from typing import Any

import foxglove

from hil import schemas
from hil.live.timing import Bounds, LiveTiming
from hil.recording import to_jsonable
from protocol.messages import State, Status, Telemetry, TorqueCommand

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
        self.robot_ids = list(robot_ids)
        # One timing per robot (a fleet's robots each have their own deadlines and epoch).
        self.timings = {r: LiveTiming(bounds) for r in self.robot_ids}
        self.reference = reference
        self.epochs: dict[str, int] = {}
        self.context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        self.port = int(self.server.port)
        for robot in self.robot_ids:
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

    def _log(self, topic: str, data: dict[str, Any], log_time: int) -> None:
        ch = self.channel(topic)
        if ch.has_sinks():  # nobody subscribed: no JSON to build
            ch.log(data, log_time=int(log_time))

    def on_message(self, topic: str, msg: Any, recv_ns: int) -> None:
        """One decoded protocol message received on ``topic`` (its robot's timing counts it
        when the robot is one of this view's)."""
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

    def on_can(self, channel: str, frame: dict[str, Any], recv_ns: int) -> None:
        """One CAN frame as the recorder's JSON (:func:`can_frame_record`)."""
        self._log(f"can/{channel}", frame, recv_ns)

    def tick(self, now_ns: int | None = None, backlog: int = 0) -> dict[str, dict[str, Any]]:
        """Publish each robot's timing figures (call once a second); returns them by robot."""
        now = time.monotonic_ns() if now_ns is None else now_ns
        snaps = {r: t.snapshot(now, backlog) for r, t in self.timings.items()}
        for robot, snap in snaps.items():
            self._log(f"hil/{robot}/{schemas.TIMING}", snap, now)
        return snaps

    def close(self) -> None:
        """Stop the server: every client sees its connection closed."""
        self.server.stop()


def _mirror(msg: Any) -> dict[str, Any]:
    return {**to_jsonable(msg), "type": type(msg).__name__}

"""JSON Schemas of everything ``hil`` records (:mod:`hil.folder.recording`) or serves live
(:mod:`hil.bench.live`), derived from the definitions.

A protocol message's schema comes from ``protocol.messages.SPECS`` (field order, kind and range),
a CAN frame's from the CANSimple dataclasses of ``protocol.can.codec``, so a field added to the
protocol is typed here without an edit. The robot's pose uses Foxglove's well-known
``foxglove.PoseInFrame`` and ``foxglove.FrameTransform`` (JSON profile), which its 3D panel draws.
A record is the recorder's JSON mirror of a decoded message: the dataclass's fields, the class's
``TAG`` and ``type`` (the class name), every property typed and required, no other allowed.
"""

from __future__ import annotations

import math
import re
from dataclasses import fields
from typing import Any

from protocol import messages as pm
from protocol.can import codec
from protocol.keys import ROBOT_ID_RE

#: A JSON Schema document (draft 2020-12) or a Foxglove message as JSON: free-form by nature,
#: its keys the standard's (docs/architecture.md, "Free-form records").
Json = dict[str, Any]

GENERIC: Json = {"type": "object", "additionalProperties": True}

_KIND_SCHEMA = {
    pm._ROBOT_ID: {"type": "string", "pattern": f"^{ROBOT_ID_RE.pattern}$"},
    pm._NAME: {"type": "string", "pattern": f"^{pm._NAME_RE.pattern}$"},
    pm._LAW: {"type": "string", "pattern": f"^{pm._LAW_RE.pattern}$"},
}


def _field_schema(kind: int, lo: float, hi: float) -> Json:
    if kind == pm._INT:
        return {"type": "integer", "minimum": int(lo), "maximum": int(hi)}
    if kind == pm._FLOAT:
        return {"type": "number", "minimum": lo, "maximum": hi}
    if kind == pm._COUNTERS:
        # "properties": {} says nothing to a validator; Foxglove-family viewers (Lichtblick,
        # Foxglove Studio) refuse an object schema without it, and with it the whole channel.
        return {
            "type": "object",
            "properties": {},
            "maxProperties": pm.MAX_COUNTERS,
            "propertyNames": {"pattern": f"^{pm._NAME_RE.pattern}$"},
            "additionalProperties": {"type": "integer", "minimum": 0, "maximum": int(hi)},
        }
    return dict(_KIND_SCHEMA[kind])


def message_schema(cls: type) -> Json:
    """The schema of the recorder's JSON of one protocol message class (``SPECS[cls]``)."""
    props: Json = {
        "TAG": {"type": "integer", "const": cls.TAG},  # type: ignore[attr-defined]
        "type": {"type": "string", "const": cls.__name__},
        **{name: _field_schema(kind, lo, hi) for name, kind, lo, hi in pm.SPECS[cls]},
    }
    return _object(f"hil.{cls.__name__}", props, cls.__doc__)


def _struct(title: str, props: Json) -> Json:
    """An object with exactly these properties, every one required."""
    return {
        "type": "object",
        "title": title,
        "properties": props,
        "required": list(props),
        "additionalProperties": False,
    }


def _object(title: str, props: Json, doc: str | None = None) -> Json:
    """A channel's schema: :func:`_struct` under the draft's ``$schema``, the title first."""
    draft = "https://json-schema.org/draft/2020-12/schema"
    out: Json = {"$schema": draft, "title": title, **_struct(title, props)}
    if doc:
        out["description"] = " ".join(doc.split())
    return out


MESSAGE_SCHEMAS: dict[str, Json] = {cls.__name__: message_schema(cls) for cls in pm.SPECS}

# One JSON type per field: a Foxglove-family viewer's JSON Schema parser takes one "type" name
# and drops the whole channel for a union (docs/live.md). A decoded float signal is a finite
# number: the codec refuses a frame carrying NaN or an infinity (CanDecodeError "non_finite"),
# which is recorded as refused, its value in decode_error and its bytes in data.
_CAN_TYPES: dict[str, Json] = {
    "int": {"type": "integer"},
    "Cmd": {"type": "integer", "minimum": 0, "maximum": 0x1F},
    "bool": {"type": "boolean"},
    "float": {"type": "number"},
}


def can_frame_schema() -> Json:
    """A CAN frame as the recorder writes it: the raw frame, and either the CANSimple message
    it decodes to (``message``: the class name, ``fields``: its signals, each typed from the
    class) or why the codec refused it (``decode_reason``: the codec's word, e.g.
    ``non_finite``; ``decode_error``: with the detail)."""
    signals: dict[str, Json] = {}
    classes: list[type] = codec.Message.__subclasses__()
    for cls in classes:  # every message class: the list grows while it is walked
        classes.extend(cls.__subclasses__())
        for f in fields(cls):
            typed = _CAN_TYPES.get(str(f.type))
            if typed is None:
                raise TypeError(f"{cls.__name__}.{f.name}: no JSON type for {f.type!r}")
            if signals.setdefault(f.name, typed) != typed:
                raise TypeError(f"CAN field {f.name} has two types across messages")
    frame = _object(
        "hil.CanFrame",
        {
            "arbitration_id": {"type": "integer", "minimum": 0, "maximum": 0x1FFFFFFF},
            "data": {"type": "string", "pattern": "^([0-9a-f]{2}){0,64}$"},
            "dlc": {"type": "integer", "minimum": 0, "maximum": 64},
            "is_remote_frame": {"type": "boolean"},
            "message": {"type": "string", "enum": sorted(c.__name__ for c in classes)},
            "fields": {
                "type": "object",
                "properties": signals,
                "required": ["node"],
                "additionalProperties": False,
            },
            "decode_reason": {"type": "string", "pattern": "^[a-z_]+$"},
            "decode_error": {"type": "string"},
        },
        "A CAN frame and what the CANSimple codec decodes it to.",
    )
    frame["required"] = ["arbitration_id", "data", "dlc", "is_remote_frame"]
    frame["oneOf"] = [
        {"required": ["message", "fields"]},
        {"required": ["decode_reason", "decode_error"]},
    ]
    return frame


RECORDER_ERROR = _object(
    "hil.RecorderError",
    {"topic": {"type": "string"}, "error": {"type": "string"}},
    "A message the recorder failed to write (the run goes on).",
)
REJECTED = _object(
    "hil.Rejected",
    {
        "topic": {"type": "string"},
        "reason": {"type": "string", "pattern": "^[a-z_]+$"},
        "raw": {"type": "string", "pattern": "^([0-9a-f]{2})*$"},
        "by": {"type": "string", "pattern": "^[a-z][a-z0-9_]*$"},
    },
    "A payload refused, as hex: by the service that received it (by: its role; reason: "
    "protocol.messages.DecodeError's, or wrong_robot) or by the recorder's own decoder "
    "(by: recorder).",
)

# Foxglove's well-known schemas (foxglove-sdk schemas/jsonschema), by their names: the 3D panel
# recognises a channel by the schema name.
_NUMBER = {"type": "number"}
_TIME = _struct(
    "time",
    {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
)
_VECTOR3 = _struct("foxglove.Vector3", dict.fromkeys("xyz", _NUMBER))
_QUATERNION = _struct("foxglove.Quaternion", dict.fromkeys("xyzw", _NUMBER))
POSE_IN_FRAME = _object(
    "foxglove.PoseInFrame",
    {
        "timestamp": _TIME,
        "frame_id": {"type": "string"},
        "pose": _struct("foxglove.Pose", {"position": _VECTOR3, "orientation": _QUATERNION}),
    },
    "A timestamped pose for an object or reference frame in 3D space",
)
FRAME_TRANSFORM = _object(
    "foxglove.FrameTransform",
    {
        "timestamp": _TIME,
        "parent_frame_id": {"type": "string"},
        "child_frame_id": {"type": "string"},
        "translation": _VECTOR3,
        "rotation": _QUATERNION,
    },
    "A transform between two reference frames in 3D space",
)

WORLD_FRAME = "world"
POSE = "pose"  # hil/<robot_id>/pose: foxglove.PoseInFrame of each State
TF = "tf"  # hil/<robot_id>/tf: foxglove.FrameTransform world -> <robot_id>
CAN_FRAME = can_frame_schema()


def schema_for_topic(topic: str) -> Json:
    """The schema of a recorded topic (:data:`GENERIC` for a topic nobody defined)."""
    if topic.startswith("can/"):
        return CAN_FRAME
    m = _HIL_TOPIC.fullmatch(topic)
    return _SUFFIX_SCHEMA.get(m.group(1), GENERIC) if m else _FIXED.get(topic, GENERIC)


def schema_name(topic: str, schema: Json) -> str:
    """The MCAP schema name: the schema's title (Foxglove matches well-known ones by it), or
    the topic with dots for an untitled one."""
    return str(schema.get("title") or topic.replace("/", "."))


def _stamp(t_ns: int) -> dict[str, int]:
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def _quaternion(theta: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(theta / 2.0), "w": math.cos(theta / 2.0)}


def pose_in_frame(t_ns: int, x: float, y: float, theta: float) -> Json:
    """foxglove.PoseInFrame of a planar pose (x, y, heading theta) in the world frame."""
    return {
        "timestamp": _stamp(t_ns),
        "frame_id": WORLD_FRAME,
        "pose": {"position": {"x": x, "y": y, "z": 0.0}, "orientation": _quaternion(theta)},
    }


def frame_transform(t_ns: int, child: str, x: float, y: float, theta: float) -> Json:
    """foxglove.FrameTransform world -> ``child`` of a planar pose."""
    return {
        "timestamp": _stamp(t_ns),
        "parent_frame_id": WORLD_FRAME,
        "child_frame_id": child,
        "translation": {"x": x, "y": y, "z": 0.0},
        "rotation": _quaternion(theta),
    }


def _num(description: str) -> Json:
    return {"type": "number", "description": description, "minimum": 0}


def _count(description: str) -> Json:
    return {"type": "integer", "minimum": 0, "description": description}


def _unknown_at_first(description: str) -> Json:
    return {"type": "number", "minimum": 0, "description": description + " (absent until known)"}


# Figures unknown at the start of a run, or without a certificate, are left out of the message
# rather than null: the JSON Schema parser of Foxglove-family viewers (Lichtblick, Foxglove
# Studio) takes one "type" name per field and refuses the channel for ["number", "null"].
_OPTIONAL_TIMING = (
    "command_age_now_ms", "command_age_max_ms", "d_star_ms", "age_margin_ms",
    "lateness_now_us", "lateness_max_us", "deadline_misses",
)  # fmt: skip


TIMING = "live/timing"  # hil/<robot_id>/live/timing: the live view's once-a-second figures
LIVE_TIMING = _object(
    "hil.LiveTiming",
    {
        "t_s": _num("seconds since the live view saw the first State"),
        "states": _count("States seen"),
        "commands": _count("TorqueCommands seen"),
        "command_age_now_ms": _unknown_at_first(
            "at the newest State: its sample time - the sample time of the newest command "
            "seen before it (the command in force, as the live view saw it)"
        ),
        "command_age_max_ms": _unknown_at_first("the largest command_age_now_ms so far: live D"),
        "d_star_ms": _unknown_at_first("D*: the largest command age the certificate allows"),
        "age_margin_ms": {
            "type": "number",
            "description": "D* - command_age_max_ms (negative: D > D* so far; absent until "
            "both are known)",
        },
        "lateness_now_us": _unknown_at_first(
            "the newest command's compute start - the previous one's - Ts, at least 0: how "
            "late the controller's tick ran after its predecessor"
        ),
        "lateness_max_us": _unknown_at_first("the largest lateness_now_us so far"),
        "deadline_misses": _count(
            "the controller's own count (its Status; absent until one arrived)"
        ),
        "states_without_command": _count(
            "States the controller was meant to answer (one per control period below the "
            "plant's sample rate) that no command was computed from within 0.1 s + Ts of "
            "their arrival"
        ),
        "max_abs_v": _num("largest |v| so far, m/s"),
        "max_abs_omega": _num("largest |omega| so far, rad/s"),
        "view_backlog": _count(
            "messages the live view had received and not yet served (grows when the view "
            "falls behind the run)"
        ),
        "verdict": {"type": "string", "enum": ["PASS", "FAIL", "INCONCLUSIVE", "WAITING"]},
        "reasons": {"type": "string", "description": "why, in one line ('' for PASS)"},
    },
    "The live view's timing figures, once a second: live estimates; summary.json holds the "
    "run's measured figures (docs/realtime.md).",
)
LIVE_TIMING["required"] = [k for k in LIVE_TIMING["required"] if k not in _OPTIONAL_TIMING]
REFERENCE = "reference"  # hil/<robot_id>/reference: foxglove.PoseInFrame of the reference
_SUFFIX_SCHEMA = {
    "state": MESSAGE_SCHEMAS["State"],
    "cmd/torque": MESSAGE_SCHEMAS["TorqueCommand"],
    "status": MESSAGE_SCHEMAS["Status"],
    "telemetry": MESSAGE_SCHEMAS["Telemetry"],
    POSE: POSE_IN_FRAME,
    TF: FRAME_TRANSFORM,
    TIMING: LIVE_TIMING,
    REFERENCE: POSE_IN_FRAME,
}
_HIL_TOPIC = re.compile(rf"hil/{ROBOT_ID_RE.pattern}/(.+)")
_FIXED = {"recorder/errors": RECORDER_ERROR, "recorder/rejected": REJECTED}

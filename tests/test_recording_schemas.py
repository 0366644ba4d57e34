"""Typed recordings (hil.schemas): every channel of a real run's recording.mcap has a JSON Schema
with every field typed, every recorded message validates against its channel's schema (with
``jsonschema``, a validator nobody here wrote), the pose is in Foxglove's well-known schemas, and
a recording written before the schemas were typed still reads."""

from __future__ import annotations

import json
import math
import shutil
import struct
from pathlib import Path

import jsonschema
import pytest
from mcap.reader import make_reader

from hil import schemas
from hil.bench.recorder import RecordingWriter, rewrite_complete, to_jsonable
from hil.folder.recording import (
    list_topics,
    read_attachments,
    read_messages,
    read_metadata,
    read_topic_payloads,
)
from protocol.messages import SPECS, State, TorqueCommand
from tests.viewer_schema import viewer_refuses

FIXTURE = Path(__file__).parent / "fixtures" / "recording_untyped.mcap"


def _untyped_properties(schema: dict, where: str = "") -> list[str]:
    """Every property of ``schema`` (recursively) that has no type: a schema that says
    nothing about a field is what the typed recording replaces."""
    bad = []
    for name, sub in (schema.get("properties") or {}).items():
        here = f"{where}.{name}"
        if not ({"type", "const", "anyOf", "enum"} & set(sub)):
            bad.append(here)
        bad += _untyped_properties(sub, here)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        bad += _untyped_properties(extra, f"{where}[*]")
    if schema.get("type") == "object" and extra is True:
        bad.append(f"{where} (any property)")
    return bad


def _channels_and_messages(path: Path):
    with open(path, "rb") as f:
        yield from make_reader(f).iter_messages()


@pytest.mark.realtime
def test_every_message_of_a_real_run_validates_against_its_channels_typed_schema(tmp_path):
    from tests.run_helpers import PASSES, clean_scenario, hil_run

    out = tmp_path / "run"
    hil_run(out, str(clean_scenario(tmp_path)), "--duration", "1", expect=PASSES)
    rec = out / "recording.mcap"
    validators: dict[int, jsonschema.Draft202012Validator] = {}
    per_topic: dict[str, int] = {}
    for schema, channel, message in _channels_and_messages(rec):
        if channel.id not in validators:
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            doc = json.loads(schema.data)
            jsonschema.Draft202012Validator.check_schema(doc)
            assert not _untyped_properties(doc), (channel.topic, _untyped_properties(doc))
            assert doc["additionalProperties"] is False, channel.topic
            assert viewer_refuses(doc) == [], channel.topic  # Foxglove parses every channel
            validators[channel.id] = jsonschema.Draft202012Validator(doc)
        errors = list(validators[channel.id].iter_errors(json.loads(message.data)))
        assert not errors, (channel.topic, message.data[:300], errors[0].message)
        per_topic[channel.topic] = per_topic.get(channel.topic, 0) + 1
    # The run's streams are all there (the CAN path runs live as shadow by default), and
    # each State has its pose beside it.
    for topic in ("state", "cmd/torque", "telemetry", "status", "pose", "tf"):
        assert per_topic.get(f"hil/robot0/{topic}", 0) > 0, per_topic
    assert any(t.startswith("can/") for t in per_topic), per_topic
    assert per_topic["hil/robot0/pose"] == per_topic["hil/robot0/tf"]
    assert per_topic["hil/robot0/pose"] == per_topic["hil/robot0/state"]
    names = {}
    with open(rec, "rb") as f:
        summary = make_reader(f).get_summary()
    for ch in summary.channels.values():
        names[ch.topic] = summary.schemas[ch.schema_id].name
    assert names["hil/robot0/pose"] == "foxglove.PoseInFrame"
    assert names["hil/robot0/tf"] == "foxglove.FrameTransform"
    assert names["hil/robot0/state"] == "hil.State"


def test_the_message_schemas_follow_the_protocols_definitions():
    for cls, spec in SPECS.items():
        doc = schemas.MESSAGE_SCHEMAS[cls.__name__]
        assert doc["required"] == ["TAG", "type", *(name for name, *_ in spec)]
    state = schemas.MESSAGE_SCHEMAS["State"]["properties"]
    assert state["x"]["type"] == "number" and state["seq"]["type"] == "integer"
    assert state["robot_id"]["type"] == "string"


def _valid(topic: str, data: dict) -> bool:
    return jsonschema.Draft202012Validator(schemas.schema_for_topic(topic)).is_valid(data)


def test_a_wrong_message_fails_its_schema():
    msg = State("robot0", 7, 100, 120, 1.0, -2.0, math.pi, 0.5, -0.25)
    good = to_jsonable(msg) | {"type": "State"}
    assert _valid("hil/robot0/state", good)
    assert not _valid("hil/robot0/state", good | {"x": "1.0"})  # a string for a float
    assert not _valid("hil/robot0/state", good | {"seq": 1.5})  # a float for an int
    assert not _valid("hil/robot0/state", good | {"extra": 1})
    assert not _valid("hil/robot0/state", {k: v for k, v in good.items() if k != "omega"})
    assert not _valid("hil/robot0/state", good | {"type": "TorqueCommand"})
    assert not _valid("hil/robot0/cmd/torque", good)  # a State is not a TorqueCommand
    frame = {"arbitration_id": 46, "data": "00", "dlc": 1, "is_remote_frame": False}
    refused = {"decode_reason": "wrong_dlc", "decode_error": "wrong_dlc: 1 byte"}
    assert _valid("can/hil0", frame | refused)
    assert not _valid("can/hil0", frame | {"decode_error": "short"})  # without its reason
    assert not _valid("can/hil0", frame)  # neither decoded nor refused
    decoded = frame | {"message": "SetInputTorque", "fields": {"node": 1, "torque_nm": 0.5}}
    assert _valid("can/hil0", decoded)
    assert not _valid("can/hil0", decoded | {"fields": {"node": 1, "torque_nm": True}})
    assert not _valid("can/hil0", decoded | {"fields": {"node": 1, "torque_nm": "nan"}})
    assert not _valid("can/hil0", decoded | {"message": "NoSuchMessage"})


def test_pose_helpers_give_unit_quaternions_of_the_heading():
    p = schemas.pose_in_frame(3_500_000_000, 1.0, 2.0, math.pi / 2)
    assert _valid("hil/r/pose", p) and p["timestamp"] == {"sec": 3, "nsec": 500_000_000}
    q = p["pose"]["orientation"]
    assert math.isclose(q["z"] ** 2 + q["w"] ** 2, 1.0)
    assert math.isclose(2 * math.atan2(q["z"], q["w"]), math.pi / 2)
    tf = schemas.frame_transform(1, "r", 1.0, 2.0, -1.0)
    assert _valid("hil/r/tf", tf) and tf["child_frame_id"] == "r"


def test_the_recorder_writes_a_rejected_payload_on_its_own_typed_channel(tmp_path):
    from hil.bench.recorder import Recorder
    from protocol.messages import encode

    path = tmp_path / "r.mcap"
    rec = Recorder(RecordingWriter(path))
    rec.queue.append(("hil/robot0/state", 10, b"\xc1"))
    rec.queue.append(("hil/robot0/state", 20, encode(State("robot0", 0, 1, 2, 0, 0, 0, 0, 0.0))))
    rec.queue.append(("hil/robot0/cmd/torque", 30, b"\x92\x02"))
    rec.close()
    got = {m.topic: m.data for m in read_messages(path)}
    assert got["recorder/rejected"]["topic"] == "hil/robot0/cmd/torque"
    assert set(got) == {"recorder/rejected", "hil/robot0/state", "hil/robot0/pose", "hil/robot0/tf"}
    for m in read_messages(path):
        assert _valid(m.topic, m.data), m


def test_a_recording_written_before_the_schemas_were_typed_still_reads(tmp_path):
    with open(FIXTURE, "rb") as f:
        for schema in make_reader(f).get_summary().schemas.values():
            assert json.loads(schema.data) == schemas.GENERIC  # it is the old format
    assert list_topics(FIXTURE) == {"hil/robot0/state": 4, "hil/robot0/cmd/torque": 3,
                                    "can/hil0": 1}  # fmt: skip
    states = list(read_messages(FIXTURE, topics=["hil/robot0/state"]))
    assert [m.data.get("seq") for m in states] == [0, 1, 2, None]
    assert states[-1].data == {"rejected": "malformed", "raw": "c1"}
    assert State(**{k: v for k, v in states[1].data.items() if k not in ("TAG", "type")}).x == 0.1
    payloads = read_topic_payloads(FIXTURE, ["hil/robot0/cmd/torque"])
    torques = [json.loads(p) for _t, _l, p in payloads]
    assert [TorqueCommand(**{k: v for k, v in d.items() if k not in ("TAG", "type")}).tau2
            for d in torques] == [-2.0] * 3  # fmt: skip
    assert read_metadata(FIXTURE)["run"]["robot_id"] == "robot0"
    assert b"duration" in read_attachments(FIXTURE)["scenario.resolved.toml"]
    # Recovery rewrites it keeping its schemas: an old file stays what it was.
    src = tmp_path / "old.mcap"
    shutil.copy(FIXTURE, src)
    counts = rewrite_complete(src, tmp_path / "new.mcap")
    assert counts["messages"] == 8
    assert list_topics(tmp_path / "new.mcap") == list_topics(FIXTURE)


def test_the_recorders_formatted_pose_is_the_schemas_pose(tmp_path):
    """hil.folder.recording.write_pose formats the JSON itself (speed): it must be exactly what the
    hil.schemas helpers build, for any pose a State can carry."""
    from hil.bench.recorder import write_pose

    path = tmp_path / "p.mcap"
    poses = [State("robot0", i, 3_000_000_007 * i, 0, 1e-7 * i - 2.5, 1e5 / (i + 1),
                   -1e3 + 17.3 * i, 0.0, 0.0) for i in range(50)]  # fmt: skip
    with RecordingWriter(path) as w:
        for st in poses:
            write_pose(w, "hil/robot0/state", st.seq, st)
    got = {(m.topic, m.log_time_ns): m.data for m in read_messages(path)}
    for st in poses:
        t, x, y, th = st.sample_time_ns, st.x, st.y, st.theta
        assert got[("hil/robot0/pose", st.seq)] == schemas.pose_in_frame(t, x, y, th)
        assert got[("hil/robot0/tf", st.seq)] == schemas.frame_transform(t, "robot0", x, y, th)


# Every topic a recording holds, by kind (hil.schemas.schema_for_topic).
RECORDED_TOPICS = [
    *(f"hil/robot0/{suffix}" for suffix in ("state", "cmd/torque", "status", "telemetry",
                                            schemas.POSE, schemas.TF, schemas.REFERENCE,
                                            schemas.TIMING)),
    "recorder/errors", "recorder/rejected", "can/hil0",
]  # fmt: skip


@pytest.mark.parametrize("topic", RECORDED_TOPICS)
def test_no_recorded_channel_has_a_field_of_two_types(topic):
    """One JSON type per field in every recorded channel's schema: no union of number and
    string (the CAN float signals' first schema), no list of types, no anyOf -- a
    Foxglove-family viewer refuses such a schema and drops the channel (tests/viewer_schema.py
    states its parser's rules; the old CAN schema is refused by them, test_live_viewer.py)."""
    schema = schemas.schema_for_topic(topic)
    assert schema is not schemas.GENERIC
    assert viewer_refuses(schema) == []


def test_a_recording_of_a_nan_torque_frame_validates_and_parses_in_the_viewers(tmp_path):
    """Frames sent on a real zenoh_can bus, received through python-can's Notifier into the
    run's Recorder (as hil run records its CAN bus), written to an MCAP file: a NaN and an
    infinite Set_Input_Torque are refused frames (decode_reason non_finite, the value in
    decode_error, no fields), the finite ones decoded with their floats as numbers; every
    message validates against its channel's schema, which a viewer parses."""
    import can

    from hil.bench.recorder import Recorder
    from tests.procs import free_tcp_port

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    torque = 1 << 5 | 0x0E  # node 1's Set_Input_Torque
    sent = [
        can.Message(arbitration_id=torque, data=struct.pack("<ff", math.nan, 0.0)),
        can.Message(arbitration_id=torque, data=struct.pack("<ff", -math.inf, 0.0)),
        can.Message(arbitration_id=torque, data=struct.pack("<ff", 0.25, 0.0)),
        can.Message(arbitration_id=1 << 5 | 0x09, data=struct.pack("<ff", 1.5, -0.5)),
        can.Message(arbitration_id=1 << 5 | 0x17, is_remote_frame=True),
    ]
    for m in sent:
        m.is_extended_id = False
    path = tmp_path / "r.mcap"
    rec = Recorder(RecordingWriter(path))
    rx = can.Bus(interface="zenoh_can", channel="nan0", endpoint=endpoint)
    tx = can.Bus(interface="zenoh_can", channel="nan0", endpoint=endpoint)
    try:
        notifier = can.Notifier(rx, [lambda m: rec.on_can("nan0", m)], timeout=0.05)
        try:
            # the two members meet (Zenoh's discovery): a probe frame that comes through
            probe = can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False)
            heard = can.BufferedReader()
            notifier.add_listener(heard)
            for _ in range(200):
                tx.send(probe)
                if heard.get_message(0.05) is not None:
                    break
            else:
                pytest.fail("the two zenoh_can members never met")
            for m in sent:
                tx.send(m)
            got = 0  # every frame sent has reached the recorder (then close() writes it)
            while got < len(sent) and (msg := heard.get_message(10.0)) is not None:
                got += msg.arbitration_id != 0x7FF
            assert got == len(sent)
        finally:
            notifier.stop()
    finally:
        tx.shutdown()
        rx.shutdown()
    rec.close()
    with open(path, "rb") as f:
        messages = list(make_reader(f).iter_messages())
    assert messages
    for schema, _channel, message in messages:
        doc = json.loads(schema.data)
        assert schema.name == "hil.CanFrame" and viewer_refuses(doc) == []
        jsonschema.Draft202012Validator(doc).validate(json.loads(message.data))
    records = [m.data for m in read_messages(path) if m.data["arbitration_id"] != 0x7FF]
    assert len(records) == len(sent)
    nan, inf, finite, estimates, request = records
    for refused, value in ((nan, "nan"), (inf, "-inf")):
        assert refused["decode_reason"] == "non_finite" and "fields" not in refused
        assert refused["decode_error"] == f"non_finite: Input_Torque={value}"
    assert finite["fields"] == {"node": 1, "torque_nm": 0.25}
    assert estimates["fields"] == {"node": 1, "pos_rev": 1.5, "vel_rev_s": -0.5}
    assert request["message"] == "Request" and request["fields"] == {"node": 1, "cmd": 0x17}

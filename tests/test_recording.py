"""MCAP recordings (hil.folder.recording): JSON mirror channels readable back by topic and log
time."""

from __future__ import annotations

import json
import math

from mcap.reader import make_reader

from hil.bench.recorder import RecordingWriter
from hil.folder.recording import list_topics, read_messages, read_metadata
from protocol.messages import State, decode, encode


def test_round_trip_by_topic_in_log_time_order(tmp_path):
    path = tmp_path / "r.mcap"
    with RecordingWriter(path, metadata={"robot_id": "robot0"}) as w:
        w.write("hil/robot0/state", 30, {"seq": 2, "x": 1.5})
        w.write("hil/robot0/state", 10, {"seq": 0, "x": 0.5}, publish_time_ns=5)
        w.write("hil/robot0/cmd/torque", 20, {"tau1": -3.3, "raw": b"\x01\xff"})
    msgs = list(read_messages(path))
    assert [m.log_time_ns for m in msgs] == [10, 20, 30]
    assert msgs[0].publish_time_ns == 5 and msgs[0].data == {"seq": 0, "x": 0.5}
    assert msgs[1].data["raw"] == "01ff"  # bytes as hex: JSON has no bytes
    states = list(read_messages(path, topics=["hil/robot0/state"]))
    assert [m.data["seq"] for m in states] == [0, 2]
    assert list_topics(path) == {"hil/robot0/state": 2, "hil/robot0/cmd/torque": 1}
    assert read_metadata(path)["run"]["robot_id"] == "robot0"


def test_channels_are_json_with_a_jsonschema_for_foxglove(tmp_path):
    path = tmp_path / "r.mcap"
    with RecordingWriter(path) as w:
        w.write("hil/robot0/state", 1, {"v": float("nan")})
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert channel.message_encoding == "json"
            assert schema.encoding == "jsonschema"
            json.loads(schema.data)
            # NaN is not JSON: it is written as a string, so every reader can parse the file.
            assert json.loads(message.data) == {"v": "nan"}


def test_a_protocol_message_survives_the_mirror(tmp_path):
    from dataclasses import asdict

    msg = State("robot0", 7, 100, 120, 1.0, -2.0, math.pi, 0.5, -0.25)
    assert decode(encode(msg)) == msg
    path = tmp_path / "r.mcap"
    with RecordingWriter(path) as w:
        w.write("hil/robot0/state", 120, asdict(msg), publish_time_ns=120)
    (m,) = list(read_messages(path))
    assert State(**m.data) == msg


def _write_chunks(path, n: int, spill: bool) -> int:
    """n messages, one chunk each (flush_interval 0): the net memory the writer kept (bytes)."""
    import tracemalloc

    tracemalloc.start()
    try:
        w = RecordingWriter(path, flush_interval=0.0, spill_indexes=spill)
        for i in range(n // 10):  # the first chunks warm up the writer's caches
            w.write(f"hil/robot0/topic{i % 12}", 1_000 + i, {"i": i})
        before = tracemalloc.get_traced_memory()[0]
        for i in range(n // 10, n):
            w.write(f"hil/robot0/topic{i % 12}", 1_000 + i, {"i": i})
        kept = tracemalloc.get_traced_memory()[0] - before
        w.close()
    finally:
        tracemalloc.stop()
    return kept


def test_chunk_indexes_are_spilled_so_a_long_recording_keeps_flat_memory(tmp_path):
    n = 3000
    spilled = _write_chunks(tmp_path / "spilled.mcap", n, spill=True)
    kept = _write_chunks(tmp_path / "kept.mcap", n, spill=False)
    # Same file, byte for byte: the summary carries the same chunk indexes.
    assert (tmp_path / "spilled.mcap").read_bytes() == (tmp_path / "kept.mcap").read_bytes()
    with open(tmp_path / "spilled.mcap", "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and len(summary.chunk_indexes) == n
    assert [m.data for m in read_messages(tmp_path / "spilled.mcap")][-1]["i"] == n - 1
    # The mcap writer's own list costs ~0.5 kB a chunk (20 chunks/s in hil run); spilled, the
    # writer keeps a few bytes a chunk at most.
    assert kept > 300 * (n - n // 10)
    assert spilled < 20 * (n - n // 10)

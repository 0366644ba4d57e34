"""The recorder of a run: what it receives, written to the run's MCAP recording (read back by
:mod:`hil.folder.recording`).

Every message is stored as a JSON mirror of its msgpack payload (encoding ``json``, one
``jsonschema`` per topic from :mod:`hil.schemas`; the robot's pose also as Foxglove's
``foxglove.PoseInFrame`` and ``foxglove.FrameTransform``); untyped schemas read the same. JSON,
not msgpack: ``json`` + ``jsonschema`` is a well-known MCAP profile that ``mcap cat --json`` and
Foxglove decode with no plug-in. CAN frames likewise (id, data as hex, decoded signals). The
decoding (tens of microseconds a message) is paid by the recorder, never by the loop.

Crash safety (docs/reliability.md, "Crash-safe runs": why 0.05 s): the writer closes its chunk
and flushes at least every ``flush_interval``; the readers (:mod:`hil.folder.recording`) read a
truncated file up to its last whole chunk, and :func:`rewrite_complete` makes it a complete,
indexed MCAP (``hil recover``).
"""

from __future__ import annotations

import collections
import json
import math
import struct
import tempfile
import threading
import time
import zlib
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, BinaryIO, TypedDict

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Attachment, AttachmentIndex, Channel, Message, Metadata, Schema
from mcap.writer import CompressionType, IndexType, Writer

from hil.folder.recording import RecordedMessage, stream_records
from hil.observe import TapReader
from hil.schemas import POSE, TF, WORLD_FRAME, schema_for_topic, schema_name
from protocol.can.codec import CanDecodeError
from protocol.can.codec import decode as can_decode
from protocol.can.drive_link import from_message
from protocol.messages import DecodeError, Status, decode
from runtime.zsession import payload_bytes

PROFILE = ""

_PLAIN = frozenset((int, str, bool, type(None)))


def to_jsonable(value: Any) -> Any:
    """A JSON-safe copy of a decoded msgpack value (bytes as hex, non-finite floats as str)."""
    # Exact types first: the recorder calls this for every message (thousands a second), and
    # the ABC check for Mapping below was half of its cost.
    kind = type(value)
    if kind in _PLAIN:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    if kind is dict or isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, bytes | bytearray | memoryview):
        return bytes(value).hex()
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, int | str):
        return value
    if hasattr(value, "_asdict"):
        return to_jsonable(value._asdict())
    if hasattr(value, "__dataclass_fields__"):
        return {k: to_jsonable(getattr(value, k)) for k in value.__dataclass_fields__}
    if hasattr(value, "item"):  # numpy scalars
        return to_jsonable(value.item())
    return repr(value)


class _SpilledIndexes:
    """The writer's chunk indexes, spilled to a temporary file as each chunk closes (why:
    docs/reliability.md, "Crash-safe runs"); the writer only appends to and iterates over it."""

    def __init__(self) -> None:
        self._file = tempfile.TemporaryFile(prefix="hil-chunk-index-")  # noqa: SIM115
        self._builder = RecordBuilder()

    def append(self, index: Any) -> None:
        index.write(self._builder)
        self._file.write(self._builder.end())

    def __iter__(self) -> Iterator[_RawRecord]:
        self._file.flush()
        self._file.seek(0)
        for head in iter(lambda: self._file.read(9), b""):  # opcode and length of each record
            (length,) = struct.unpack("<Q", head[1:])
            yield _RawRecord(head + self._file.read(length))
        self._file.seek(0, 2)

    def close(self) -> None:
        self._file.close()


class _RawRecord(bytes):
    """One serialized record, written as is into the writer's summary."""

    def write(self, builder: Any) -> None:
        builder.write(self)


def _register_topic(writer: Writer, topic: str) -> int:
    """A new channel for ``topic``, JSON with its own jsonschema (:func:`schema_for_topic`)."""
    typed = schema_for_topic(topic)
    schema = writer.register_schema(schema_name(topic, typed), "jsonschema",
                                    json.dumps(typed).encode())  # fmt: skip
    return writer.register_channel(topic, "json", schema)


class RecordingWriter:
    """Writes messages (dicts) to one MCAP file, one channel per topic. Not thread-safe."""

    def __init__(
        self,
        path: str | Path,
        metadata: Mapping[str, str] | None = None,
        flush_interval: float = 0.05,
        spill_indexes: bool = True,
    ) -> None:
        self.path = Path(path)
        self._stream: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._stream, compression=CompressionType.ZSTD)
        self._spilled: _SpilledIndexes | None = None
        chunk_indices = getattr(self._writer, "_Writer__chunk_indices", None)
        if spill_indexes and isinstance(chunk_indices, list):
            self._spilled = _SpilledIndexes()
            self._writer._Writer__chunk_indices = self._spilled  # type: ignore[attr-defined]
        self._flush_interval = float(flush_interval)
        self._next_flush = time.monotonic() + self._flush_interval
        self._writer.start(profile=PROFILE, library="hil-smc-bench")
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.count = 0
        self._closed = False
        if metadata:
            self._writer.add_metadata("run", {str(k): str(v) for k, v in metadata.items()})

    def write(
        self,
        topic: str,
        log_time_ns: int,
        data: Mapping[str, Any],
        publish_time_ns: int | None = None,
        jsonable: bool = False,
    ) -> None:
        """Append one message; ``jsonable``: ``data`` is already :func:`to_jsonable`'s output
        (the recorder converts as it decodes, and a second walk would cost every message)."""
        safe = data if jsonable else to_jsonable(data)
        payload = json.dumps(safe, separators=(",", ":")).encode()
        self.write_payload(topic, log_time_ns, payload, publish_time_ns)

    def write_payload(
        self, topic: str, log_time_ns: int, payload: bytes, publish_time_ns: int | None = None
    ) -> None:
        """Append one message already serialized as JSON (``payload``: UTF-8 bytes); its
        topic's channel registered on first use (:func:`_register_topic`)."""
        ch = self._channels.get(topic)
        if ch is None:
            ch = self._channels[topic] = _register_topic(self._writer, topic)
        seq = self._seq.get(topic, 0)
        self._seq[topic] = seq + 1
        self._writer.add_message(
            channel_id=ch,
            log_time=int(log_time_ns),
            data=payload,
            publish_time=int(publish_time_ns if publish_time_ns is not None else log_time_ns),
            sequence=seq,
        )
        self.count += 1
        self.maybe_flush()

    def maybe_flush(self) -> None:
        """Close the chunk and flush the file when ``flush_interval`` has passed (call it also
        when idle: a quiet stretch must not keep the last messages in memory)."""
        now = time.monotonic()
        if now >= self._next_flush and not self._closed:
            self._writer.flush()
            self._next_flush = now + self._flush_interval

    def add_attachment_file(
        self,
        name: str,
        path: str | Path,
        media_type: str = "application/msgpack",
        time_ns: int | None = None,
    ) -> None:
        """A file carried inside the recording (the hop logs: the recording alone then
        reproduces every timing figure), streamed from disk a block at a time: ``mcap``'s
        ``Writer.add_attachment`` holds the data three times (an hour's ~1 GB of hop logs would
        need GBs) and nothing public streams. The record is byte for byte the one it writes
        (CRCs, index, statistics; tests/test_long_run_parts.py compares), through the Writer's
        private state; without that state (another ``mcap``) the public call."""
        now = time.time_ns() if time_ns is None else int(time_ns)
        w = self._writer
        private = ("_Writer__stream", "_Writer__flush", "_Writer__statistics",
                   "_Writer__attachment_indexes", "_Writer__index_types",
                   "_Writer__enable_data_crcs", "_Writer__data_section_crc")  # fmt: skip
        if not all(hasattr(w, a) for a in private):
            self._writer.add_attachment(now, now, name, media_type, Path(path).read_bytes())
            return

        size = Path(path).stat().st_size
        name_b, media_b = name.encode(), media_type.encode()
        body = (
            struct.pack("<QQ", now, now)
            + struct.pack("<I", len(name_b)) + name_b
            + struct.pack("<I", len(media_b)) + media_b
            + struct.pack("<Q", size)
        )  # fmt: skip
        length = len(body) + size + 4
        w._Writer__flush()
        stream = w._Writer__stream
        offset = stream.tell()
        head = struct.pack("<BQ", int(Opcode.ATTACHMENT), length) + body
        crc = zlib.crc32(body)

        def put(data: bytes) -> None:  # into the file and the data section's CRC, if kept
            stream.write(data)
            if w._Writer__enable_data_crcs:
                w._Writer__data_section_crc = zlib.crc32(data, w._Writer__data_section_crc)

        put(head)
        copied = 0
        with open(path, "rb") as f:
            while copied < size and (block := f.read(min(1 << 20, size - copied))):
                put(block)
                crc = zlib.crc32(block, crc)
                copied += len(block)
        if copied != size:
            raise OSError(f"{path}: changed while it was attached ({copied} of {size} bytes)")
        put(struct.pack("<I", crc))
        w._Writer__statistics.attachment_count += 1
        if w._Writer__index_types & IndexType.ATTACHMENT:
            w._Writer__attachment_indexes.append(
                AttachmentIndex(
                    offset=offset,
                    length=1 + 8 + length,
                    create_time=now,
                    log_time=now,
                    data_size=size,
                    name=name,
                    media_type=media_type,
                )
            )

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()
            if self._spilled is not None:
                self._spilled.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def rewrite_complete(
    src: str | Path,
    dst: str | Path,
    attachments: Mapping[str, bytes | Path] | None = None,
    extra: Iterable[RecordedMessage] = (),
) -> dict[str, int]:
    """A complete, indexed MCAP at ``dst`` from a possibly truncated ``src``: its every whole
    record, plus ``attachments`` (data or a file), plus the messages ``extra`` (sorted by log
    time; each before the first message of ``src`` logged after it, on its topic's channel,
    registered if ``src`` has none). Counts (``restored``: the messages of ``extra`` written)."""
    counts = {"messages": 0, "attachments": 0, "restored": 0}
    pending = collections.deque(extra)
    with open(dst, "wb") as out:
        w = Writer(out, compression=CompressionType.ZSTD)
        w.start(profile=PROFILE, library="hil-smc-bench (recovered)")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        by_topic: dict[str, int] = {}

        def add_extra(until: float) -> None:
            while pending and pending[0].log_time_ns <= until:
                m = pending.popleft()
                if m.topic not in by_topic:
                    by_topic[m.topic] = _register_topic(w, m.topic)
                data = json.dumps(to_jsonable(m.data), separators=(",", ":")).encode()
                w.add_message(by_topic[m.topic], m.log_time_ns, data, m.publish_time_ns,
                              m.sequence)  # fmt: skip
                counts["restored"] += 1

        for rec in stream_records(src):
            if isinstance(rec, Schema):
                schema_ids[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                channel_ids[rec.id] = w.register_channel(
                    rec.topic, rec.message_encoding, schema_ids.get(rec.schema_id, 0),
                    dict(rec.metadata),
                )  # fmt: skip
                by_topic.setdefault(rec.topic, channel_ids[rec.id])
            elif isinstance(rec, Message) and rec.channel_id in channel_ids:
                add_extra(rec.log_time)
                w.add_message(
                    channel_ids[rec.channel_id], rec.log_time, rec.data, rec.publish_time,
                    rec.sequence,
                )  # fmt: skip
                counts["messages"] += 1
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Attachment) and rec.name not in (attachments or {}):
                w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type,
                                 rec.data)  # fmt: skip
                counts["attachments"] += 1
        add_extra(math.inf)
        for name, data in (attachments or {}).items():
            now = time.time_ns()
            blob = data.read_bytes() if isinstance(data, Path) else bytes(data)
            w.add_attachment(now, now, name, "application/octet-stream", blob)
            counts["attachments"] += 1
        w.finish()
    return counts


def write_pose(writer: RecordingWriter, state_topic: str, log_time_ns: int, state: Any) -> None:
    """The State's pose beside it as Foxglove's ``hil/<id>/pose`` (foxglove.PoseInFrame) and
    ``hil/<id>/tf`` (foxglove.FrameTransform world -> <id>): its 3D panel shows the robot.

    Formatted here, not dumped from dicts: the recorder writes both for every State, and
    json.dumps of nested dicts tripled its cost (a State's floats are finite: ``repr`` is JSON)."""
    base = state_topic.rsplit("/", 1)[0]
    t = state.sample_time_ns
    sec, nsec = divmod(t, 1_000_000_000)
    half = 0.5 * state.theta
    stamp = f'{{"sec":{sec},"nsec":{nsec}}}'
    xyz = f'{{"x":{state.x!r},"y":{state.y!r},"z":0.0}}'
    quat = f'{{"x":0.0,"y":0.0,"z":{math.sin(half)!r},"w":{math.cos(half)!r}}}'
    pose = (f'{{"timestamp":{stamp},"frame_id":"{WORLD_FRAME}",'
            f'"pose":{{"position":{xyz},"orientation":{quat}}}}}')  # fmt: skip
    writer.write_payload(f"{base}/{POSE}", log_time_ns, pose.encode(), t)
    tf = (f'{{"timestamp":{stamp},"parent_frame_id":"{WORLD_FRAME}","child_frame_id":'
          f'{json.dumps(state.robot_id)},"translation":{xyz},"rotation":{quat}}}')  # fmt: skip
    writer.write_payload(f"{base}/{TF}", log_time_ns, tf.encode(), t)


class CanFrameRecord(TypedDict, total=False):
    """A CAN frame as the recording and the live view show it (schema ``hil.CanFrame``)."""

    arbitration_id: int
    data: str  # hex
    dlc: int
    is_remote_frame: bool
    message: str  # the CANSimple message it decodes to
    fields: dict[str, Any]  # that message's fields (protocol.can.codec.to_jsonable)
    decode_reason: str  # or why it does not decode
    decode_error: str


def can_frame_record(msg: Any) -> CanFrameRecord:
    """A python-can message as the recording and the live view show it (schema
    ``hil.CanFrame``): its fields, and the CANSimple message it decodes to (or why not)."""
    data: CanFrameRecord = {
        "arbitration_id": msg.arbitration_id,
        "data": bytes(msg.data).hex(),
        "dlc": msg.dlc,
        "is_remote_frame": bool(msg.is_remote_frame),
    }
    try:
        m = can_decode(from_message(msg))
        data["message"] = type(m).__name__
        data["fields"] = to_jsonable(m)  # finite numbers: the codec refuses non-finite ones
    except Exception as exc:  # a frame the codec refuses is still recorded, with why
        data["decode_reason"] = exc.reason if isinstance(exc, CanDecodeError) else "malformed"
        data["decode_error"] = str(exc)
    return data


class Recorder:
    """Receives the robot's status, its services' taps (every message they sent and every
    payload they refused, :mod:`hil.observe`) and every CAN frame; writes them off-thread.
    ``same_clock``: the services share this process's clock (not a lab run)."""

    def __init__(self, writer: RecordingWriter, same_clock: bool = True) -> None:
        self.writer = writer
        self.taps = TapReader(same_clock)
        self.queue: collections.deque[tuple[str, int, Any]] = collections.deque()
        self.states = 0
        self.statuses: dict[str, Any] = {}
        self.status_ns: dict[str, int] = {}  # when each role's newest status arrived
        # Frames the recorder's CAN socket dropped (None: no CAN, or a bus with no socket).
        self.can_socket_drops: int | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drain, name="recorder", daemon=True)
        self._thread.start()

    def on_zenoh(self, sample: Any) -> None:
        self.queue.append((str(sample.key_expr), time.monotonic_ns(), payload_bytes(sample)))

    def on_can(self, channel: str, msg: Any) -> None:
        self.queue.append((f"can/{channel}", time.monotonic_ns(), msg))

    def _write_one(self, topic: str, t: int, payload: Any) -> None:
        if topic.startswith("can/"):
            self.writer.write(topic, t, can_frame_record(payload), jsonable=True)
            return
        for m in self.taps.read(topic, t, payload):
            if m.rejected:
                self._write_rejected(m.topic, m.log_time_ns, m.payload, m.rejected, m.by)
            else:
                self._write_message(m.topic, m.log_time_ns, m.payload)

    def _write_rejected(self, topic: str, t: int, payload: bytes, reason: str, by: str) -> None:
        """A payload refused (by a service on receipt, or by the recorder's own decoder), on
        its own channel: each topic's messages fit its schema."""
        rejected = {"topic": topic, "reason": reason, "raw": payload.hex(), "by": by}
        self.writer.write("recorder/rejected", t, rejected, jsonable=True)

    def _write_message(self, topic: str, t: int, payload: bytes) -> None:
        try:
            m = decode(payload)
        except DecodeError as exc:
            self._write_rejected(topic, t, payload, exc.reason, "recorder")
            return
        d = to_jsonable(m)  # one walk; asdict first made a deep copy for nothing
        d["type"] = type(m).__name__
        publish = getattr(m, "send_time_ns", None) or getattr(m, "time_ns", None)
        self.writer.write(topic, t, d, publish_time_ns=publish, jsonable=True)
        if topic.endswith("/state"):
            self.states += 1
            write_pose(self.writer, topic, t, m)
        if isinstance(m, Status):
            self.statuses[m.role] = m
            self.status_ns[m.role] = t

    def _drain(self) -> None:
        while not (self._stop.is_set() and not self.queue):
            if not self.queue:
                self.writer.maybe_flush()  # a quiet stretch still reaches the disk in time
                time.sleep(0.005)
                continue
            topic, t, payload = self.queue.popleft()
            try:
                self._write_one(topic, t, payload)
            except Exception as exc:  # a recorder must never take the run down
                self.writer.write("recorder/errors", t, {"topic": topic, "error": repr(exc)})

    def close(self, attachments: dict[str, Path] | None = None) -> None:
        """Drain, attach the files streamed from disk (never whole in memory), finish the MCAP."""
        self._stop.set()
        self._thread.join(timeout=30)
        for name, path in (attachments or {}).items():
            self.writer.add_attachment_file(name, path)
        self.writer.close()

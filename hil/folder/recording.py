"""MCAP recordings of a run: a writer for the recorder and a reader for reports.

Every message is stored as a JSON mirror of its msgpack payload (encoding ``json``, one
``jsonschema`` per topic from :mod:`hil.schemas`; the robot's pose also as Foxglove's
``foxglove.PoseInFrame`` and ``foxglove.FrameTransform``); untyped schemas read the same. JSON,
not msgpack: ``json`` + ``jsonschema`` is a well-known MCAP profile that ``mcap cat --json`` and
Foxglove decode with no plug-in. CAN frames likewise (id, data as hex, decoded signals). The
decoding (tens of microseconds a message) is paid by the recorder, never by the loop.

``log_time_ns`` of a :class:`RecordedMessage` is when the recorder received it
(``time.monotonic_ns()``); ``publish_time_ns`` the sender's own stamp if it has one, else the
log time.

Crash safety (docs/reliability.md, "Crash-safe runs": why 0.05 s): the writer closes its chunk
and flushes at least every ``flush_interval``; the readers here read a truncated file up to its
last whole chunk, and :func:`rewrite_complete` makes it a complete, indexed MCAP (``hil recover``).
"""

from __future__ import annotations

import collections
import io
import json
import math
import struct
import tempfile
import time
import zlib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Attachment, AttachmentIndex, Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap.writer import CompressionType, IndexType, Writer

from hil.schemas import POSE, TF, WORLD_FRAME, schema_for_topic, schema_name

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


@dataclass(frozen=True)
class RecordedMessage:
    topic: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: dict[str, Any]


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


def _summary(path: str | Path) -> Any:
    """The recording's summary section; None unless it ends with it (a clean finish)."""
    try:
        with open(path, "rb") as f:
            return make_reader(f).get_summary()
    except Exception:  # a truncated file makes the indexed reader raise anything
        return None


def is_complete(path: str | Path) -> bool:
    """Whether the recording ends with its summary and footer (a clean finish)."""
    return _summary(path) is not None


def _stream_records(path: str | Path) -> Iterator[Any]:
    """Every whole record of a possibly truncated recording, in file order."""
    with open(path, "rb") as f:
        reader = StreamReader(f, record_size_limit=None)
        try:
            yield from reader.records
        except Exception:  # the tail of a killed writer: stop at the last whole record
            return


def _streamed_messages(path: str | Path) -> Iterator[tuple[str, Message]]:
    """(topic, Message) of every whole message of a possibly truncated recording, in file order."""
    channels: dict[int, str] = {}
    for rec in _stream_records(path):
        if isinstance(rec, Channel):
            channels[rec.id] = rec.topic
        elif isinstance(rec, Message) and rec.channel_id in channels:
            yield channels[rec.channel_id], rec


def read_messages(
    path: str | Path, topics: Iterable[str] | None = None
) -> Iterator[RecordedMessage]:
    """Every message (of ``topics`` if given), by log time; a truncated file to its last chunk."""
    wanted = list(topics) if topics is not None else None
    if is_complete(path):
        with open(path, "rb") as f:
            for _s, ch, m in make_reader(f).iter_messages(topics=wanted, log_time_order=True):
                yield _recorded(ch.topic, m)
        return
    found = [_recorded(t, m) for t, m in _streamed_messages(path) if wanted is None or t in wanted]
    yield from sorted(found, key=lambda m: m.log_time_ns)


def _recorded(topic: str, m: Message) -> RecordedMessage:
    return RecordedMessage(topic, m.log_time, m.publish_time, m.sequence, json.loads(m.data))


def topic_values(path: str | Path, topic: str, key: str) -> Iterator[Any]:
    """``data[key]`` of every message on ``topic`` of a possibly truncated recording, in file
    order, one message at a time (an hour's States never sit in memory as dicts)."""
    if is_complete(path):
        for _t, _log, payload in read_topic_payloads(path, [topic]):
            yield json.loads(payload).get(key)
        return
    for t, m in _streamed_messages(path):
        if t == topic:
            yield json.loads(m.data).get(key)


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

        for rec in _stream_records(src):
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


def list_topics(path: str | Path) -> dict[str, int]:
    """Topic -> message count, from the recording's summary section."""
    summary = _summary(path)
    if summary is None or summary.statistics is None:
        return dict(collections.Counter(m.topic for m in read_messages(path)))
    by_id = {cid: ch.topic for cid, ch in summary.channels.items()}
    return {by_id[cid]: int(n) for cid, n in summary.statistics.channel_message_counts.items()}


def read_attachments(path: str | Path, names: Iterable[str] | None = None) -> dict[str, bytes]:
    """Name -> data of the recording's attachments (optionally only ``names``)."""
    wanted = set(names) if names is not None else None
    if is_complete(path):
        with open(path, "rb") as f:
            atts = list(make_reader(f).iter_attachments())
    else:
        atts = [r for r in _stream_records(path) if isinstance(r, Attachment)]
    return {a.name: bytes(a.data) for a in atts if wanted is None or a.name in wanted}


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """Name -> metadata record of the recording."""
    with open(path, "rb") as f:
        return {record.name: dict(record.metadata) for record in make_reader(f).iter_metadata()}


def read_topic_payloads(
    path: str | Path, topics: Iterable[str]
) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log_time_ns, JSON payload bytes) of every message on ``topics``, chunk by chunk
    in file order (not sorted by log time), without decoding the payloads.

    Why: the ``mcap`` reader parses every record in Python (~20 µs a message of any topic);
    here each chunk is decompressed once and the wanted messages sliced out through its
    message-index records: an hour's recording in seconds per topic. Without a summary (a
    killed writer), :func:`read_messages` reads it."""
    wanted = set(topics)
    summary = _summary(path)
    if summary is None or not summary.chunk_indexes:
        for m in read_messages(path, topics=sorted(wanted)):
            yield m.topic, m.log_time_ns, json.dumps(m.data).encode()
        return
    ids = {cid: ch.topic for cid, ch in summary.channels.items() if ch.topic in wanted}
    if not ids:
        return
    q = struct.Struct("<Q")
    with open(path, "rb") as f:
        for ci in summary.chunk_indexes:
            present = [(cid, off) for cid, off in ci.message_index_offsets.items() if cid in ids]
            if not present:
                continue
            f.seek(ci.chunk_start_offset + 1 + 8)  # the Chunk record's fields
            chunk = Chunk.read(ReadDataStream(io.BytesIO(f.read(ci.chunk_length - 1 - 8))))
            if chunk.compression not in ("", "zstd", "lz4"):
                raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
            stream, size = get_chunk_data_stream(chunk)
            records = stream.read(size)
            for cid, index_offset in present:
                f.seek(index_offset)
                head = f.read(1 + 8 + 2 + 4)
                count = struct.unpack_from("<I", head, 11)[0]
                pairs = struct.unpack(f"<{count // 8}Q", f.read(count))
                topic = ids[cid]
                for i in range(0, len(pairs), 2):
                    at = pairs[i + 1]
                    length = q.unpack_from(records, at + 1)[0]
                    # message: opcode, length, channel u16, sequence u32, log and publish time
                    yield topic, pairs[i], records[at + 31 : at + 9 + length]


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

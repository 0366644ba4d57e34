"""MCAP recordings of a run, read: the recorder's file (:mod:`hil.bench.recorder` writes it) as
the reports, the recovery and the tests read it.

Every message is stored as a JSON mirror of its msgpack payload (encoding ``json``, one
``jsonschema`` per topic from :mod:`hil.schemas`); see :mod:`hil.bench.recorder`.
``log_time_ns`` of a :class:`RecordedMessage` is when the recorder received it
(``time.monotonic_ns()``); ``publish_time_ns`` the sender's own stamp if it has one, else the
log time.

Crash safety (docs/reliability.md, "Crash-safe runs"): the readers here read a truncated file up
to its last whole chunk; :func:`hil.bench.recorder.rewrite_complete` makes it a complete,
indexed MCAP (``hil recover``).
"""

from __future__ import annotations

import collections
import io
import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Chunk, Message
from mcap.stream_reader import StreamReader, get_chunk_data_stream


@dataclass(frozen=True)
class RecordedMessage:
    topic: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: dict[str, Any]


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


def stream_records(path: str | Path) -> Iterator[Any]:
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
    for rec in stream_records(path):
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
        atts = [r for r in stream_records(path) if isinstance(r, Attachment)]
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

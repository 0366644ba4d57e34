"""MCAP recordings of a run: a writer for the recorder and a reader for reports.

Encoding choice: every message is stored as a JSON mirror of its msgpack payload (MCAP message
encoding ``json`` with a ``jsonschema`` schema per topic). The wire format stays msgpack; the
recording decodes it once, off the real-time path, in the recorder. Why JSON and not the raw
msgpack bytes: ``json`` + ``jsonschema`` is a well-known MCAP profile that the ``mcap`` CLI
(``mcap cat --json``) and Foxglove decode and plot with no plug-in, whereas msgpack is not one
of Foxglove's encodings. CAN frames are stored the same way (arbitration id, data as hex,
decoded signals when the codec knows them). The cost (a few tens of microseconds a message)
is paid by the recorder process, never by the controller or the plant.

Reader API (what ``hil report`` uses)::

    from hil.recording import read_messages, list_topics
    for msg in read_messages(path, topics=["hil/robot0/state"]):
        msg.topic, msg.log_time_ns, msg.publish_time_ns, msg.data  # data: a dict

``log_time_ns`` is when the recorder received the message (``time.monotonic_ns()``), and
``publish_time_ns`` the sender's own stamp when the message carries one (else the log time).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

PROFILE = ""
GENERIC_SCHEMA: dict[str, Any] = {"type": "object", "additionalProperties": True}


def to_jsonable(value: Any) -> Any:
    """A JSON-safe copy of a decoded msgpack value (bytes as hex, non-finite floats as str)."""
    if isinstance(value, bytes | bytearray | memoryview):
        return bytes(value).hex()
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if value is None or isinstance(value, bool | int | str):
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


class RecordingWriter:
    """Writes messages (dicts) to one MCAP file, one channel per topic.

    Not thread-safe: callers that receive on several threads hold their own lock.
    """

    def __init__(self, path: str | Path, metadata: Mapping[str, str] | None = None) -> None:
        self.path = Path(path)
        self._stream: BinaryIO = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._stream, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library="hil-smc-bench")
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        self.count = 0
        self._closed = False
        if metadata:
            self._writer.add_metadata("run", {str(k): str(v) for k, v in metadata.items()})

    def channel(self, topic: str, schema: Mapping[str, Any] | None = None) -> int:
        ch = self._channels.get(topic)
        if ch is None:
            schema_id = self._writer.register_schema(
                name=topic.replace("/", "."),
                encoding="jsonschema",
                data=json.dumps(dict(schema or GENERIC_SCHEMA)).encode(),
            )
            ch = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
            self._channels[topic] = ch
            self._seq[topic] = 0
        return ch

    def write(
        self,
        topic: str,
        log_time_ns: int,
        data: Mapping[str, Any],
        publish_time_ns: int | None = None,
    ) -> None:
        ch = self.channel(topic)
        seq = self._seq[topic]
        self._seq[topic] = seq + 1
        payload = json.dumps(to_jsonable(data), separators=(",", ":")).encode()
        self._writer.add_message(
            channel_id=ch,
            log_time=int(log_time_ns),
            data=payload,
            publish_time=int(publish_time_ns if publish_time_ns is not None else log_time_ns),
            sequence=seq,
        )
        self.count += 1

    def add_attachment(
        self, name: str, data: bytes, media_type: str = "application/msgpack"
    ) -> None:
        """A file carried inside the recording (the services' hop logs: a recording alone then
        reproduces every timing figure of the run)."""
        import time

        now = time.time_ns()
        self._writer.add_attachment(now, now, name, media_type, bytes(data))

    def add_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        self._writer.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._stream.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_messages(
    path: str | Path, topics: Iterable[str] | None = None
) -> Iterator[RecordedMessage]:
    """Every message of the recording (optionally only ``topics``), in log-time order."""
    wanted = list(topics) if topics is not None else None
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(topics=wanted, log_time_order=True):
            yield RecordedMessage(
                topic=channel.topic,
                log_time_ns=message.log_time,
                publish_time_ns=message.publish_time,
                sequence=message.sequence,
                data=json.loads(message.data),
            )


def list_topics(path: str | Path) -> dict[str, int]:
    """Topic -> message count, from the recording's summary section."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or summary.statistics is None:
        counts: dict[str, int] = {}
        for m in read_messages(path):
            counts[m.topic] = counts.get(m.topic, 0) + 1
        return counts
    by_id = {cid: ch.topic for cid, ch in summary.channels.items()}
    return {by_id[cid]: int(n) for cid, n in summary.statistics.channel_message_counts.items()}


def read_attachments(path: str | Path, names: Iterable[str] | None = None) -> dict[str, bytes]:
    """Name -> data of the recording's attachments (optionally only ``names``)."""
    wanted = set(names) if names is not None else None
    out: dict[str, bytes] = {}
    with open(path, "rb") as f:
        for att in make_reader(f).iter_attachments():
            if wanted is None or att.name in wanted:
                out[att.name] = bytes(att.data)
    return out


def read_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """Name -> metadata record of the recording."""
    out: dict[str, dict[str, str]] = {}
    with open(path, "rb") as f:
        for record in make_reader(f).iter_metadata():
            out[record.name] = dict(record.metadata)
    return out

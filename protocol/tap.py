"""A service's tap: the messages it sent (and the payloads it refused), handed to observers in
batches on ``hil/<robot_id>/tap/<role>`` instead of observers subscribing to the loop's keys.

Why: an observer subscribed to ``hil/<robot_id>/state`` or ``.../cmd/torque`` (``hil run``'s
recorder, the live view) receives every State and command as the loop does, so each one is
sent twice and wakes a third process on the loop's two cores: that cost the loop's transport
about a third of its time (docs/performance.md). A tap batch is one put every
``TAP_INTERVAL_NS`` (50 ms), off the critical path, and carries the same payload bytes.

Wire format: one msgpack array ``[TAP_TAG, TAP_VERSION, robot_id, role, seq, send_time_ns,
entries]``; ``send_time_ns`` is the sender's clock when the batch left; each entry is an array
``[stream, stamp_ns, payload, rejected]``:

- ``stream``: the key suffix the payload travelled on (``state``, ``cmd/torque``,
  ``telemetry``, ``status``; :data:`protocol.keys.STREAMS`);
- ``stamp_ns``: when the sender put it on the wire (for a refused payload: when it arrived),
  on the sender's clock;
- ``payload``: the message's bytes exactly as they travelled (at most
  :data:`protocol.messages.MAX_MESSAGE_BYTES`; a longer refused payload is cut there);
- ``rejected``: ``""`` for a message the service sent, else the reason word the service
  refused a received payload with (:mod:`protocol.messages`; ``wrong_robot``, ...).

Decoding is strict, as for messages: :func:`decode_batch` returns a whole batch or raises one
:class:`protocol.messages.DecodeError` (``too_large``, ``malformed``, ``trailing_bytes``,
``not_array``, ``bad_header``, ``unknown_type``, ``unknown_version``, ``missing_field``,
``extra_field``, ``wrong_type``, ``out_of_range``, ``bad_identifier``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import NamedTuple

import msgpack

from protocol.keys import STREAMS, is_valid_robot_id
from protocol.messages import MAX_MESSAGE_BYTES, SEQ_MAX, TIME_MAX, DecodeError, unpack_array

TAP_TAG = 100  # outside the messages' tags: a batch is never mistaken for a message
TAP_VERSION = 1
TAP_INTERVAL_NS = 50_000_000  # a batch at least this often while there is something to send
MAX_BATCH_ENTRIES = 4096  # a batch is sent early when it holds this many
MAX_BATCH_BYTES = 1 << 20  # what a decoder accepts (a full batch of the largest payloads)
_WORD = re.compile(r"[a-z][a-z0-9_]{0,31}")


class TapEntry(NamedTuple):
    stream: str
    stamp_ns: int
    payload: bytes
    rejected: str = ""


@dataclass(frozen=True, slots=True)
class TapBatch:
    robot_id: str
    role: str
    seq: int
    send_time_ns: int
    entries: tuple[TapEntry, ...]


def encode_batch(
    robot_id: str, role: str, seq: int, send_time_ns: int, entries: list[TapEntry]
) -> bytes:
    """One batch's bytes (the caller built the entries: :class:`runtime.tap.Tap`)."""
    return msgpack.packb(
        [TAP_TAG, TAP_VERSION, robot_id, role, seq, send_time_ns, entries], use_bin_type=True
    )


def _int(value: object, name: str, hi: int) -> int:
    if type(value) is not int:
        raise DecodeError("wrong_type", f"{name} must be an int, got {type(value)}")
    if not 0 <= value <= hi:
        raise DecodeError("out_of_range", f"{name} = {value}")
    return value


def _word(value: object, name: str) -> str:
    if type(value) is not str:
        raise DecodeError("wrong_type", f"{name} must be a str, got {type(value)}")
    if _WORD.fullmatch(value) is None:
        raise DecodeError("bad_identifier", f"{name} = {value!r}")
    return value


def _entry(item: object, i: int) -> TapEntry:
    if type(item) is not list:
        raise DecodeError("wrong_type", f"entry {i} must be an array")
    if len(item) != 4:
        raise DecodeError("missing_field" if len(item) < 4 else "extra_field", f"entry {i}")
    stream, stamp, payload, rejected = item
    if type(stream) is not str:
        raise DecodeError("wrong_type", f"entry {i} stream must be a str")
    if stream not in STREAMS:
        raise DecodeError("bad_identifier", f"entry {i} stream = {stream!r}")
    if type(payload) is not bytes:
        raise DecodeError("wrong_type", f"entry {i} payload must be bytes")
    if len(payload) > MAX_MESSAGE_BYTES:
        raise DecodeError("too_large", f"entry {i} payload of {len(payload)} bytes")
    if rejected != "":
        _word(rejected, f"entry {i} rejected")
    elif type(rejected) is not str:
        raise DecodeError("wrong_type", f"entry {i} rejected must be a str")
    return TapEntry(stream, _int(stamp, f"entry {i} stamp_ns", TIME_MAX), payload, rejected)


def decode_batch(data: object) -> TapBatch:
    """A whole batch, or one :class:`DecodeError` (reasons in the module docstring)."""
    obj = unpack_array(data, MAX_BATCH_BYTES)
    if obj[0] != TAP_TAG:
        raise DecodeError("unknown_type", obj[0])
    if obj[1] != TAP_VERSION:
        raise DecodeError("unknown_version", obj[1])
    if len(obj) != 7:
        raise DecodeError("missing_field" if len(obj) < 7 else "extra_field", "tap batch")
    _, _, robot_id, role, seq, send_ns, entries = obj
    if type(robot_id) is not str:
        raise DecodeError("wrong_type", "robot_id must be a str")
    if not is_valid_robot_id(robot_id):
        raise DecodeError("bad_identifier", f"robot_id = {robot_id!r}")
    if type(entries) is not list:
        raise DecodeError("wrong_type", "entries must be an array")
    if len(entries) > MAX_BATCH_ENTRIES:
        raise DecodeError("out_of_range", f"{len(entries)} > {MAX_BATCH_ENTRIES} entries")
    return TapBatch(
        robot_id,
        _word(role, "role"),
        _int(seq, "seq", SEQ_MAX),
        _int(send_ns, "send_time_ns", TIME_MAX),
        tuple(_entry(e, i) for i, e in enumerate(entries)),
    )

"""Messages: hypothesis round trips and each strict-decoding rule (protocol/messages.py)."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import messages as m
from protocol.keys import ROBOT_ID_RE
from protocol.rejections import RejectionCounter

_robot_id = st.from_regex(ROBOT_ID_RE, fullmatch=True).filter(lambda s: s not in (".", ".."))
_name = st.from_regex(m._NAME_RE, fullmatch=True)
_law = st.from_regex(m._LAW_RE, fullmatch=True)


def _field_strategy(kind: int, lo: float, hi: float) -> st.SearchStrategy:
    if kind == m._INT:
        return st.integers(int(lo), int(hi))
    if kind == m._FLOAT:
        return st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    if kind == m._ROBOT_ID:
        return _robot_id
    if kind == m._NAME:
        return _name
    if kind == m._LAW:
        return _law
    return st.dictionaries(_name, st.integers(0, m.SEQ_MAX), max_size=m.MAX_COUNTERS)


def message_strategy(cls: type) -> st.SearchStrategy:
    spec = m.SPECS[cls]
    return st.builds(cls, **{n: _field_strategy(k, lo, hi) for n, k, lo, hi in spec})


any_message = st.one_of(*(message_strategy(cls) for cls in m.SPECS))


@settings(max_examples=400, deadline=None)
@given(any_message)
def test_protocol_every_message_round_trips(msg: m.Message) -> None:
    data = m.encode(msg)
    assert len(data) <= m.MAX_MESSAGE_BYTES
    back = m.decode(data)
    assert type(back) is type(msg)
    assert back == msg
    assert m.decode_as(type(msg), data) == msg


def _state(**kw) -> m.State:
    base = dict(
        robot_id="r1", seq=7, sample_time_ns=10**15, send_time_ns=10**15 + 5,
        x=1.0, y=-2.0, theta=0.5, v=0.4, omega=-0.2,
    )  # fmt: skip
    base.update(kw)
    return m.State(**base)


def _raw(msg: m.Message) -> list:
    return msgpack.unpackb(m.encode(msg))


def _reason(data: object) -> str:
    with pytest.raises(m.DecodeError) as info:
        m.decode(data)
    return info.value.reason


def test_protocol_decoded_fields_have_exact_types() -> None:
    s = m.decode(m.encode(_state(x=1, theta=np.float32(0.5), seq=np.int64(3))))
    assert type(s.x) is float and type(s.theta) is float and type(s.seq) is int
    assert s.x == 1.0 and s.seq == 3


@pytest.mark.parametrize(
    ("index", "value", "reason"),
    [
        (3, True, "wrong_type"),  # seq: a bool is not an int
        (3, 1.0, "wrong_type"),  # seq: a float is not an int
        (3, -1, "out_of_range"),
        (3, 2**63, "out_of_range"),
        (6, 1, "wrong_type"),  # x: an int is not a float
        (6, "1.0", "wrong_type"),
        (6, None, "wrong_type"),
        (6, math.nan, "non_finite"),
        (6, math.inf, "non_finite"),
        (6, -math.inf, "non_finite"),
        (6, 2.0e6, "out_of_range"),
        (9, 1.0e3 + 1.0, "out_of_range"),  # v
        (2, "a/b", "bad_identifier"),
        (2, "r*", "bad_identifier"),
        (2, "", "bad_identifier"),
        (2, b"r1", "wrong_type"),
        (0, 99, "unknown_type"),
        (1, 2, "unknown_version"),
        (1, True, "bad_header"),
    ],
)
def test_protocol_field_rejections(index: int, value: object, reason: str) -> None:
    # index into [tag, version, robot_id, seq, sample_time_ns, send_time_ns, x, y, theta, v, omega]
    fields = _raw(_state())
    fields[index] = value
    assert _reason(msgpack.packb(fields)) == reason


def test_protocol_structure_rejections() -> None:
    good = _raw(_state())
    assert _reason(msgpack.packb(good[:-1])) == "missing_field"
    assert _reason(msgpack.packb([*good, 0.0])) == "extra_field"
    assert _reason(msgpack.packb({"t": 1})) == "not_array"
    assert _reason(msgpack.packb([1])) == "bad_header"
    assert _reason(m.encode(_state()) + b"\x00") == "trailing_bytes"
    assert _reason(m.encode(_state())[:-3]) == "malformed"
    assert _reason(b"") == "malformed"
    assert _reason(b"\xc1") == "malformed"  # never-used msgpack byte
    assert _reason(msgpack.packb([1, 1, "\udcff"], unicode_errors="surrogatepass")) == "malformed"
    assert _reason(b"\x91" * 5000) == "too_large"
    assert _reason(b"\x91" * 4000) == "malformed"  # too deeply nested for msgpack
    assert _reason("not bytes") == "not_bytes"
    assert _reason(None) == "not_bytes"
    assert m.decode(bytearray(m.encode(_state()))) == _state()
    assert m.decode(memoryview(m.encode(_state()))) == _state()


def test_protocol_torque_and_status_specific_rules() -> None:
    cmd = m.TorqueCommand("r1", 1, 1, 5, 6, 7, 3.3, -51.0, "pkg.mod:Law", m.FLAG_BOUNDARY_LAYER)
    assert m.decode(m.encode(cmd)) == cmd
    raw = _raw(cmd)
    raw[8] = 1.0e4 + 1.0  # tau1
    assert _reason(msgpack.packb(raw)) == "out_of_range"
    raw = _raw(cmd)
    raw[10] = "law with space"
    assert _reason(msgpack.packb(raw)) == "bad_identifier"
    raw = _raw(cmd)
    raw[11] = 2**32  # flags are uint32
    assert _reason(msgpack.packb(raw)) == "out_of_range"

    status = m.Status("r1", 1, 2, "plant", "running", m.STATUS_WATCHDOG_TRIPPED, {"lost": 3})
    assert m.decode(m.encode(status)) == status
    for counters, reason in [
        ({"Lost": 1}, "bad_identifier"),
        ({"lost": -1}, "out_of_range"),
        ({"lost": 1.0}, "wrong_type"),
        ({"lost": False}, "wrong_type"),
        ([1, 2], "wrong_type"),
        ({f"c{i}": i for i in range(65)}, "out_of_range"),
    ]:
        raw = _raw(status)
        raw[8] = counters
        assert _reason(msgpack.packb(raw)) == reason, counters

    tele = m.Telemetry("r1", 1, 2, 0.1, 0.2, 0.3, 0.01, 0.0, 0.0, 0.1, -0.1, 1.0)
    assert m.decode(m.encode(tele)) == tele
    raw = _raw(tele)
    raw[13] = 1.5  # eta is in [0, 1]
    assert _reason(msgpack.packb(raw)) == "out_of_range"


def test_protocol_decode_as_and_counted() -> None:
    data = m.encode(_state())
    with pytest.raises(m.DecodeError) as info:
        m.decode_as(m.TorqueCommand, data)
    assert info.value.reason == "unexpected_type"
    counter = RejectionCounter()
    assert m.decode_counted(data, counter, m.State) == _state()
    assert m.decode_counted(data, counter, m.TorqueCommand) is None
    assert m.decode_counted(b"\xc1", counter) is None
    assert counter.snapshot() == {"malformed": 1, "unexpected_type": 1}
    assert counter.total == 2


def test_protocol_encoder_refuses_what_the_decoder_would_reject() -> None:
    for bad, reason in [
        (_state(x=math.nan), "non_finite"),
        (_state(v=5.0e3), "out_of_range"),
        (_state(robot_id="a/b"), "bad_identifier"),
        (_state(seq=True), "wrong_type"),
        (_state(x=True), "wrong_type"),
        (_state(seq=-1), "out_of_range"),
    ]:
        with pytest.raises(m.EncodeError) as info:
            m.encode(bad)
        assert info.value.reason == reason

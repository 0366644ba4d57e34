"""100,000+ random and mutated byte strings through the msgpack decoders (seeded, repeatable):
only DecodeError escapes, every rejection is counted by reason, and whatever is accepted is a
complete, valid message (it re-encodes and decodes to itself)."""

from __future__ import annotations

import math
import random

import msgpack

from protocol import messages as m
from protocol.rejections import RejectionCounter

N_CASES = 120_000
SEED = 20240613


def _seed_messages() -> list[m.Message]:
    t = 1_700_000_000_000_000
    return [
        m.State("robot1", 41, t, t + 80_000, 1.25, -0.5, 12.3, 0.49, -0.21),
        m.TorqueCommand("robot1", 40, 41, t, t + 90_000, t + 95_000, 3.3, -51.0, "unified", 0),
        m.TorqueCommand("r-2", 2**40, 7, t, t, t, -0.0, 1e-300, "my.pkg:Law", m.FLAG_STOP),
        m.Status("plant_1", 3, t, "plant", "running", m.STATUS_WATCHDOG_TRIPPED, {"lost": 2}),
        m.Telemetry("robot1", 9, t, 0.1, -0.2, 0.03, 1e-9, 0.05, -0.4, 0.2, -0.1, 0.73),
    ]


_ODD_VALUES = [
    None, True, False, 0, -1, 1, 2**63, 2**64 - 1, -(2**63), 0.0, -0.0, 1e308, -1e308,
    math.nan, math.inf, -math.inf, 5e-324, "", "x", "a/b", "robot1", "\u00e9", b"", b"\x00",
    [], [1, 2], {}, {"a": 1}, {1: 2}, msgpack.ExtType(5, b"zz"), msgpack.Timestamp(1, 2),
]  # fmt: skip


def _pack_loose(obj: object) -> bytes:
    # Fields the normal encoder refuses (int keys, NaN...) still need to reach the decoder.
    return msgpack.packb(obj, use_bin_type=True, strict_types=False)


def _structural(rng: random.Random, fields: list) -> bytes:
    fields = list(fields)
    op = rng.randrange(8)
    i = rng.randrange(len(fields))
    if op == 0:  # type swap
        fields[i] = rng.choice(_ODD_VALUES)
    elif op == 1:  # non-finite injection into a float field
        floats = [k for k, v in enumerate(fields) if type(v) is float]
        fields[rng.choice(floats) if floats else i] = rng.choice([math.nan, math.inf, -math.inf])
    elif op == 2:  # missing field(s)
        del fields[i : i + rng.randint(1, 3)]
    elif op == 3:  # extra field(s)
        fields.extend(rng.choice(_ODD_VALUES) for _ in range(rng.randint(1, 3)))
    elif op == 4:  # tag / version out of the known set
        fields[rng.randrange(2)] = rng.choice([0, 5, 2, 1, 255, -1, 2**40])
    elif op == 5:  # out-of-range magnitudes
        v = fields[i]
        if type(v) is float:
            fields[i] = v * 10.0 ** rng.randint(4, 300) + rng.choice([1e7, -1e7])
        elif type(v) is int:
            fields[i] = rng.choice([-1, 2**63, 2**64 - 1, -(2**63)])
        else:
            fields[i] = "bad/id" if rng.random() < 0.5 else "x" * rng.randint(65, 200)
    elif op == 6:  # as a map with short keys instead of an array
        return _pack_loose({str(k): v for k, v in enumerate(fields)})
    else:  # float32 encoding of the same message (valid) or nested wrapping (invalid)
        if rng.random() < 0.5:
            return msgpack.packb(fields, use_single_float=True)
        return _pack_loose([fields])
    return _pack_loose(fields)


def _mutate(rng: random.Random, data: bytes, fields: list) -> object:
    op = rng.randrange(7)
    if op == 0:  # random bytes
        return rng.randbytes(rng.randint(0, 96))
    if op == 1:  # bit flips
        buf = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        return bytes(buf)
    if op == 2:  # truncation
        return data[: rng.randrange(len(data))]
    if op == 3:  # trailing garbage
        return data + rng.randbytes(rng.randint(1, 8))
    if op == 4:  # random byte overwrite / insertion
        buf = bytearray(data)
        pos = rng.randrange(len(buf))
        if rng.random() < 0.5:
            buf[pos] = rng.randrange(256)
        else:
            buf[pos:pos] = rng.randbytes(rng.randint(1, 4))
        return bytes(buf)
    if op == 5 and rng.random() < 0.02:  # not bytes at all, or far too long
        return rng.choice([None, "text", 42, [1, 2], b"\x91" * 5000])
    return _structural(rng, fields)


def test_protocol_fuzz_only_decode_error_escapes_and_every_rejection_is_counted() -> None:
    rng = random.Random(SEED)
    seeds = [(m.encode(msg), msgpack.unpackb(m.encode(msg))) for msg in _seed_messages()]
    counter = RejectionCounter()
    rejected = accepted = 0
    for _ in range(N_CASES):
        data, fields = rng.choice(seeds)
        candidate = _mutate(rng, data, fields)
        try:
            msg = m.decode(candidate)
        except m.DecodeError as e:
            counter.count(e.reason)
            rejected += 1
            continue
        accepted += 1
        # Nothing half-decoded: an accepted message is complete and valid.
        assert type(msg) in m.SPECS
        assert m.decode(m.encode(msg)) == msg

    assert rejected + accepted == N_CASES
    assert counter.total == rejected == sum(counter.snapshot().values())
    by_reason = counter.snapshot()
    # The mutations reach every rule, not just the msgpack parser.
    for reason in (
        "malformed", "trailing_bytes", "not_array", "bad_header", "unknown_type",
        "unknown_version", "missing_field", "extra_field", "wrong_type", "non_finite",
        "out_of_range", "bad_identifier", "not_bytes", "too_large",
    ):  # fmt: skip
        assert by_reason.get(reason, 0) > 0, (reason, by_reason)
    assert rejected > 0.8 * N_CASES

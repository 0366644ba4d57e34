"""Sequence tracking (protocol/sequence.py), rejection counting and key expressions."""

from __future__ import annotations

import random
import threading

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol import keys
from protocol.rejections import RejectionCounter
from protocol.sequence import WINDOW, SequenceTracker, Verdict


def test_protocol_sequence_in_order_stream_is_all_fresh() -> None:
    t = SequenceTracker()
    assert all(t.observe(s) is Verdict.FRESH for s in range(100))
    assert t.counts.as_dict() == {
        "received": 100, "accepted": 100, "lost": 0, "duplicated": 0, "reordered": 0,
        "too_old": 0,
    }  # fmt: skip


def test_protocol_sequence_gap_duplicate_reorder() -> None:
    t = SequenceTracker()
    assert t.observe(10).fresh
    assert t.observe(13).fresh  # 11 and 12 missing
    assert t.counts.lost == 2
    assert t.observe(13) is Verdict.DUPLICATE
    assert t.observe(11) is Verdict.REORDERED  # late: rejected, no longer lost
    assert t.counts.lost == 1 and t.counts.reordered == 1
    assert t.observe(11) is Verdict.DUPLICATE
    assert t.observe(10) is Verdict.DUPLICATE
    assert t.observe(14).fresh
    assert t.newest == 14
    assert t.observe(14 - WINDOW) is Verdict.TOO_OLD
    c = t.counts
    assert (c.received, c.accepted, c.duplicated, c.too_old) == (8, 3, 3, 1)


def test_protocol_sequence_large_jump_clears_window() -> None:
    t = SequenceTracker()
    t.observe(0)
    t.observe(1000)
    assert t.counts.lost == 999
    assert t.observe(999) is Verdict.REORDERED
    assert t.observe(1) is Verdict.TOO_OLD
    t.reset()
    assert t.observe(0).fresh  # a restarted sender is accepted after an explicit reset


@given(st.permutations(list(range(40))), st.integers(0, 2**62), st.randoms())
def test_protocol_sequence_counts_match_a_simple_model(
    order: list[int], base: int, rnd: random.Random
) -> None:
    # Deliver a shuffled stream with some duplicates and some numbers dropped; compare the
    # tracker with a straightforward model that remembers everything.
    delivered = [base + s for s in order if rnd.random() > 0.2]
    delivered += [rnd.choice(delivered) for _ in range(5)] if delivered else []
    rnd.shuffle(delivered)
    t = SequenceTracker()
    seen: set[int] = set()
    newest = None
    for s in delivered:
        v = t.observe(s)
        if s in seen:
            assert v is Verdict.DUPLICATE
        elif newest is None or s > newest:
            assert v is Verdict.FRESH
        else:
            assert v is Verdict.REORDERED  # the window (64) covers the 40 numbers here
        if newest is None or s > newest:
            newest = s
        seen.add(s)
    if delivered:
        first = delivered[0]
        # Lost counts the numbers never received between the first accepted one and the newest.
        assert t.counts.lost == (newest - first + 1) - len({s for s in seen if s >= first})
        assert t.counts.accepted + t.counts.duplicated + t.counts.reordered == len(delivered)


def test_protocol_rejection_counter_is_exact_under_threads() -> None:
    counter = RejectionCounter()

    def hammer(reason: str) -> None:
        for _ in range(20_000):
            counter.count(reason)

    threads = [threading.Thread(target=hammer, args=(r,)) for r in ("a", "b", "a", "c")]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert counter.snapshot() == {"a": 40_000, "b": 20_000, "c": 20_000}
    assert counter.total == 80_000 and counter.get("a") == 40_000 and counter.get("z") == 0


def test_protocol_keys() -> None:
    assert keys.state_key("r1") == "hil/r1/state"
    assert keys.torque_key("r1") == "hil/r1/cmd/torque"
    assert keys.telemetry_key("r1") == "hil/r1/telemetry"
    assert keys.status_key("r1") == "hil/r1/status"
    assert keys.robot_prefix("r1") == "hil/r1/**"
    assert keys.parse_key("hil/robot_2/cmd/torque") == ("robot_2", "torque")
    for bad in ("", "a/b", "a*", "$*", "a#", "a?", "@r", "a b", ".", "..", "x" * 65, None, 3):
        with pytest.raises(keys.InvalidRobotIdError):
            keys.state_key(bad)  # type: ignore[arg-type]
    for bad in ("hil/r1/other", "x/r1/state", "hil/a*/state", "hil/r1"):
        with pytest.raises(ValueError):
            keys.parse_key(bad)

"""Receiver-side sequence tracking: gaps (lost), duplicates and reordering, counted not guessed.

docs/design.md, section 3, and summary.json's `messages` (counts sent, received, lost, duplicated,
reordered). Only a message newer than the last accepted one is *fresh* and may be used; a late
(reordered) or repeated message is rejected and counted, because a stale torque applied after
a newer one is worse than none.

A window of the last ``WINDOW`` sequence numbers below the newest tells a late arrival (it
filled a gap: ``lost`` goes down by one, ``reordered`` up by one) from a duplicate. Anything
older than the window is counted as ``too_old`` (it cannot be told apart; it is rejected
either way, and stays counted in ``lost``). Numbers are counted lost only between the first
accepted one and the newest. Pure state, no clock, no locks: one tracker per stream, fed
from one thread.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from protocol.hoplog import RxVerdict

WINDOW = 64


class Verdict(Enum):
    """What the tracker made of one sequence number."""

    FRESH = "fresh"  # newer than every accepted number: use it
    DUPLICATE = "duplicate"  # seen before: reject
    REORDERED = "reordered"  # older than the newest, never seen (it filled a gap): reject
    TOO_OLD = "too_old"  # older than the window: reject

    @property
    def fresh(self) -> bool:
        return self is Verdict.FRESH

    @property
    def code(self) -> RxVerdict:
        """The hop logs' verdict column: accepted (fresh), duplicate, or older than one already
        seen."""
        if self is Verdict.FRESH:
            return RxVerdict.ACCEPTED
        return RxVerdict.DUPLICATE if self is Verdict.DUPLICATE else RxVerdict.OLDER


@dataclass
class SequenceCounts:
    """Counts of one stream; ``lost`` is the number of sequence numbers never received so far
    (gaps below the newest, less the late arrivals that filled them)."""

    received: int = 0
    accepted: int = 0
    lost: int = 0
    duplicated: int = 0
    reordered: int = 0
    too_old: int = 0

    def as_dict(self) -> dict[str, int]:
        return {
            "received": self.received,
            "accepted": self.accepted,
            "lost": self.lost,
            "duplicated": self.duplicated,
            "reordered": self.reordered,
            "too_old": self.too_old,
        }


class SequenceTracker:
    """Tracks one stream's sequence numbers (non-negative ints, increasing by one per send)."""

    __slots__ = ("_first", "_newest", "_seen", "counts")

    def __init__(self) -> None:
        self._first = 0
        self._newest: int | None = None
        # Bit i set: sequence number (newest - i) has been received.
        self._seen = 0
        self.counts = SequenceCounts()

    @property
    def newest(self) -> int | None:
        """The newest accepted sequence number (None before the first message)."""
        return self._newest

    def observe(self, seq: int) -> Verdict:
        """Record one received sequence number and say whether it is fresh."""
        c = self.counts
        c.received += 1
        newest = self._newest
        if newest is None or seq > newest:
            if newest is not None:
                gap = seq - newest
                c.lost += gap - 1
                self._seen = ((self._seen << gap) | 1) & ((1 << WINDOW) - 1) if gap < WINDOW else 1
            else:
                self._seen = 1
                self._first = seq
            self._newest = seq
            c.accepted += 1
            return Verdict.FRESH
        age = newest - seq
        if age >= WINDOW:
            c.too_old += 1
            return Verdict.TOO_OLD
        bit = 1 << age
        if self._seen & bit:
            c.duplicated += 1
            return Verdict.DUPLICATE
        self._seen |= bit
        if seq > self._first:  # below the first accepted number it was never counted lost
            c.lost -= 1
        c.reordered += 1
        return Verdict.REORDERED

    def reset(self) -> None:
        """Forget the stream (e.g. the sender announced a restart); counts are kept."""
        self._newest = None
        self._seen = 0

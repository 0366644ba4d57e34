"""Faults on the wire, injected on purpose (the scenario's ``[faults]`` table): pure and seeded.

Both services decide from these functions alone, so a fault is a function of (seed, what,
index or time), reproducible run after run, and each service logs every fault it injected in
its hop log (so a run's lost/duplicated/reordered counts and its stalls can name them).

- every n-th: drops, duplicates and reorders of States and commands (``k % n == n - 1``);
- bursts: windows of ``length`` seconds, one per ``every`` seconds, starting at a seeded random
  offset inside each period (:func:`in_burst`): extra delay on the applied command path, CAN
  bus-off at the controller's CAN edge (its sends fail), and every State (by its sample time) or
  Zenoh command (by its send time) dropped;
- CAN frame loss: each Set_Input_Torque frame lost at the drive's receiver with probability
  ``p``, decided per (seed, node, frame index) (:func:`frame_lost`);
- the feedback path toward the controller (States on Zenoh, encoder-estimate frames on CAN):
  each item held ``feedback_delay`` plus a uniform draw in [0, ``feedback_jitter``] seconds
  before it reaches the wire, or lost with probability ``feedback_loss``, decided per (seed,
  index) (:meth:`Faults.feedback_extra_s`, :meth:`Faults.feedback_lost`). What an outside
  device is measured against, run after run, by ``hil campaign``;
- the virtual drives toward an outside device: an over-speed error at a time, bursts of
  silence, and bursts in which their encoder estimates are frozen (sent on time with stale
  content, :meth:`Faults.feedback_frozen`).
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any


def every_nth(k: int, n: int) -> bool:
    """The k-th item (from 0) is hit: every n-th, the last of each group of n (0: never)."""
    return n > 0 and k % n == n - 1


def _uniform(seed: int, *key: int) -> float:
    """A uniform number in [0, 1) from (seed, key): stable across processes and versions."""
    digest = hashlib.blake2b(struct.pack(f"<{1 + len(key)}q", seed, *key), digest_size=8).digest()
    return int.from_bytes(digest, "little") / 2.0**64


def in_burst(t_s: float, every: float, length: float, seed: int, stream: int = 0) -> bool:
    """Whether time ``t_s`` (since the epoch) lies in a burst: period k = floor(t / every)
    holds one burst of ``length`` starting at k * every + u_k (every - length), u_k seeded."""
    if every <= 0.0 or length <= 0.0 or t_s < 0.0:
        return False
    k = int(t_s // every)
    start = k * every + _uniform(seed, stream, k) * max(0.0, every - length)
    return start <= t_s < start + length


def frame_lost(p: float, seed: int, node: int, index: int) -> bool:
    """Whether the index-th torque frame to ``node`` is lost at the receiver (probability p)."""
    return p > 0.0 and _uniform(seed, 7, node, index) < p


@dataclass(frozen=True)
class Faults:
    """The ``[faults]`` table as the services read it (0 = off)."""

    state_drop_every: int = 0
    command_drop_every: int = 0
    state_duplicate_every: int = 0
    command_duplicate_every: int = 0
    command_reorder_every: int = 0
    delay_burst_every: float = 0.0
    delay_burst_length: float = 0.0
    delay_burst_extra: float = 0.0
    can_frame_loss: float = 0.0
    can_bus_off_every: float = 0.0
    can_bus_off_length: float = 0.0
    state_drop_burst_every: float = 0.0
    state_drop_burst_length: float = 0.0
    command_drop_burst_every: float = 0.0
    command_drop_burst_length: float = 0.0
    feedback_delay: float = 0.0
    feedback_jitter: float = 0.0
    feedback_loss: float = 0.0
    drive_fault_at: float = 0.0
    drive_fault_node: int = 0
    drive_silent_every: float = 0.0
    drive_silent_length: float = 0.0
    feedback_frozen_every: float = 0.0
    feedback_frozen_length: float = 0.0
    seed: int = 0

    @classmethod
    def of(cls, table: Mapping[str, Any] | None) -> Faults:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in (table or {}).items() if k in known})

    def delay_extra_s(self, t_s: float) -> float:
        """Extra delay (s) for a command arriving at ``t_s`` on the applied path."""
        burst = in_burst(t_s, self.delay_burst_every, self.delay_burst_length, self.seed, 1)
        return self.delay_burst_extra if burst else 0.0

    def bus_off(self, t_s: float) -> bool:
        return in_burst(t_s, self.can_bus_off_every, self.can_bus_off_length, self.seed, 2)

    def state_dropped(self, seq: int, t_s: float) -> bool:
        """Whether the plant drops State ``seq`` sampled at ``t_s`` (every n-th, or a burst)."""
        burst = in_burst(
            t_s, self.state_drop_burst_every, self.state_drop_burst_length, self.seed, 3
        )
        return every_nth(seq, self.state_drop_every) or burst

    def command_dropped(self, seq: int, t_s: float) -> bool:
        """Whether the controller drops command ``seq`` sent at ``t_s`` (every m-th, or a
        burst)."""
        every, length = self.command_drop_burst_every, self.command_drop_burst_length
        return every_nth(seq, self.command_drop_every) or in_burst(t_s, every, length, self.seed, 4)

    @property
    def feedback_held(self) -> bool:
        """Whether the feedback path delays, jitters or loses anything."""
        return self.feedback_delay > 0 or self.feedback_jitter > 0 or self.feedback_loss > 0

    def feedback_extra_s(self, index: int, stream: int = 0) -> float:
        """The time (s) the index-th feedback item of ``stream`` (0: States; 1 + node: a
        drive's encoder estimates) is held before the wire."""
        if self.feedback_jitter <= 0.0:
            return self.feedback_delay
        return self.feedback_delay + self.feedback_jitter * _uniform(self.seed, 8, stream, index)

    def feedback_lost(self, index: int, stream: int = 0) -> bool:
        """Whether the index-th feedback item of ``stream`` is lost on the way."""
        return (
            self.feedback_loss > 0.0 and _uniform(self.seed, 9, stream, index) < self.feedback_loss
        )

    def drive_silent(self, t_s: float) -> bool:
        """Whether the drives send nothing at run time ``t_s``."""
        return in_burst(t_s, self.drive_silent_every, self.drive_silent_length, self.seed, 5)

    def feedback_frozen(self, t_s: float) -> bool:
        """Whether the drives' encoder estimates are frozen at run time ``t_s``: sent on time,
        with the content of the last one before the burst (a stuck sensor)."""
        every, length = self.feedback_frozen_every, self.feedback_frozen_length
        return in_burst(t_s, every, length, self.seed, 6)

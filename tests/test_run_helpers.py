"""The test helpers that let a loaded host's verdict through (tests/run_helpers.py) only where
the run's own logs explain it: a certificate broken by the controller's late wake-ups."""

from __future__ import annotations

import numpy as np

from tests.run_helpers import _late_controller_unseen, fleet_outcome

MS = 1_000_000
EPOCH = 10_000 * MS
P = MS // 2  # 2 kHz
BROKEN = "certificate not held: command age D = 49.4 ms > D* = 20.4 ms by the system's own timing"


def _ticks(late_at_ms: float | None) -> dict[str, np.ndarray]:
    deadline = EPOCH + np.arange(0, 3000 * MS, P, dtype=np.int64)
    wake = deadline + 50_000
    if late_at_ms is not None:
        wake[int(late_at_ms * MS) // P] += 40 * MS
    return {"deadline_ns": deadline, "wake_ns": wake, "skipped": np.zeros(deadline.size, int)}


def _summary(cause: str, reasons: tuple[str, ...] = (BROKEN,)) -> dict:
    stall = {"t_s": 1.500, "age_s": 0.0494, "cause": cause, "owner": "system"}
    cert = {"d_star_s": 0.0204, "stalls": [stall, {**stall, "t_s": 2.5, "age_s": 0.01}]}
    return {"verdict": {"reasons": list(reasons)}, "certificate": cert}


def test_a_certificate_broken_by_a_late_controller_its_log_shows_is_explained():
    meta = {"epoch_ns": EPOCH}
    assert _late_controller_unseen(_summary("controller_late"), _ticks(1490), P, meta) == []
    # no certificate reason: nothing to explain
    assert _late_controller_unseen(_summary("state_lost", ()), _ticks(None), P, meta) == []


def test_another_cause_or_a_controller_on_time_is_not():
    meta = {"epoch_ns": EPOCH}
    lost = _late_controller_unseen(_summary("state_lost"), _ticks(1490), P, meta)
    assert len(lost) == 1 and "state_lost" in lost[0]
    # late, but far from the stall (t = 1.5 s, 49 ms): not this stall's
    assert len(_late_controller_unseen(_summary("controller_late"), _ticks(900), P, meta)) == 1
    assert len(_late_controller_unseen(_summary("controller_late"), _ticks(None), P, meta)) == 1
    assert _late_controller_unseen(_summary("controller_late"), _ticks(1490), P, {}) != []


def test_a_fleet_is_its_worst_robot():
    assert fleet_outcome(["PASS", "PASS"]) == "PASS"
    assert fleet_outcome(["PASS", "INCONCLUSIVE"]) == "INCONCLUSIVE"
    assert fleet_outcome(["INCONCLUSIVE", "FAIL", "PASS"]) == "FAIL"
    assert fleet_outcome(["PASS", "None"]) == "FAIL"  # a robot that left no verdict

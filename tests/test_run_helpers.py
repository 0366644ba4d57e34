"""The test helpers' pure parts (tests/run_helpers.py)."""

from __future__ import annotations

from tests.run_helpers import fleet_outcome


def test_a_fleet_is_its_worst_robot():
    assert fleet_outcome(["PASS", "PASS"]) == "PASS"
    assert fleet_outcome(["PASS", "INCONCLUSIVE"]) == "INCONCLUSIVE"
    assert fleet_outcome(["INCONCLUSIVE", "FAIL", "PASS"]) == "FAIL"
    assert fleet_outcome(["PASS", "None"]) == "FAIL"  # a robot that left no verdict

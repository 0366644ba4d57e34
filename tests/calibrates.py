"""``@calibrates(FIGURE, ..., injects=..., found=...)``: a known-answer test declares which timing
figures of docs/realtime.md it calibrates, what it injects and within what it finds it again.

docs/realtime.md's calibration table is written from these declarations
(``python -m tools.calibration_table --write``), and tests/test_known_answers.py fails when the
table differs from them, when a figure of the "Timing figures" table has no real-process
calibration, or when a declared figure is not one the test reads. A figure of a path is named
``sample_to_apply_zenoh (applied)``, ``sample_to_apply_can (shadow)``, etc. Arguments must be
string literals: the tool reads them from the source, without importing the tests.
"""

from __future__ import annotations

import pytest


def calibrates(*figures: str, injects: str, found: str) -> pytest.MarkDecorator:
    """Mark a test as the known answer of ``figures``: ``injects`` what it puts into the run (or
    the scripted logs), ``found`` the tolerance within which the figure must show it and why."""
    assert figures and injects and found
    return pytest.mark.calibrates(*figures, injects=injects, found=found)

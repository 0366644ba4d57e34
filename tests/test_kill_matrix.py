"""The kill matrix, 20 trials of each failure (bench/kill_matrix.py prints the same as a table
with the worst time to the safe state): every trial must reach its safe state in time.

``hil_run_kill`` is the crash-safe run: SIGKILL of ``hil run`` at trial i's seeded moment, no
process left (by PID), at most 0.1 s of States lost from the recording, and ``hil report``
recovering the folder (exit 0 or 1, never 2)."""

from __future__ import annotations

import pytest

from bench.kill_matrix import KINDS, run_trial

pytestmark = [pytest.mark.realtime, pytest.mark.slow]

TRIALS = 20


@pytest.mark.parametrize("trial", range(TRIALS))
@pytest.mark.parametrize("kind", KINDS)
def test_kill_matrix_trial(kind, trial):
    result = run_trial(kind, trial)
    assert result.ok, (kind, trial, result.safe_s, result.detail)

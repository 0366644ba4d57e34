"""Crash-safe runs: SIGKILL of ``hil run`` at random moments (seeded), 20 trials.

Each trial kills ``hil run`` by its PID at a random moment of its run, then checks: no process
is left (by PID), the recording has lost at most 0.1 s of messages before the kill, and
``hil report`` on the folder works (exit 0 or 1, never 2): it recovers the folder first (a
complete, indexed MCAP; trace.csv and summary.json rebuilt from the services' hop logs).
"""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import time

import pytest

from hil.recording import is_complete, read_attachments, read_messages
from protocol.hoplog import read_hoplog
from tests.procs import wait_until
from tests.run_helpers import alive, children_of

pytestmark = [pytest.mark.realtime, pytest.mark.slow]

TRIALS = 20
DURATION_S = 2.0
FLUSH_BOUND_S = 0.1


def _epoch(out) -> int | None:
    try:
        return int(read_hoplog(out / "plant.hoplog").meta.get("epoch_ns") or 0) or None
    except (OSError, ValueError):
        return None


@pytest.mark.parametrize("trial", range(TRIALS))
def test_sigkill_of_hil_run_at_a_random_moment_leaves_a_recoverable_folder(spawn, tmp_path, trial):
    rng = random.Random(1000 + trial)
    at_s = rng.uniform(0.1, DURATION_S + 0.5)  # into the run, up to after its end
    out = tmp_path / "run"
    run = spawn.python(
        ["-m", "hil", "run", "--duration", str(DURATION_S), "--quiet", "--no-report",
         "--out", str(out)]
    )  # fmt: skip
    assert wait_until(lambda: _epoch(out) is not None, 120), "the run never started"
    kids = children_of(run.pid)
    target = _epoch(out) + int(at_s * 1e9)
    time.sleep(max(0.0, (target - time.monotonic_ns()) / 1e9))  # to a seeded moment
    if run.poll() is not None:
        pytest.skip("hil run had already finished at the chosen moment")  # never, at +0.5 s
    kill_ns = time.monotonic_ns()
    run.send_signal(signal.SIGKILL)
    run.wait(timeout=10)
    assert wait_until(lambda: not any(alive(k) for k in kids), 15), "children left behind"

    # At most FLUSH_BOUND_S of recorded messages lost before the kill: every State the plant
    # sent up to then is in the (truncated) recording.
    plant = read_hoplog(out / "plant.hoplog")
    sent = {r[0] for r in plant.rows["samples"] if r[3] <= kill_ns - FLUSH_BOUND_S * 1e9}
    recorded = {m.data["seq"] for m in read_messages(out / "recording.mcap", ["hil/robot0/state"])}
    assert sent <= recorded, f"{len(sent - recorded)} states sent > 0.1 s before the kill lost"

    rep = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out), "--no-ideal"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert rep.returncode in (0, 1), rep.stderr[-3000:]
    assert is_complete(out / "recording.mcap")
    assert set(read_attachments(out / "recording.mcap")) >= {"plant.hoplog", "controller.hoplog"}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["recovered"] is True and summary["samples"] > 0
    assert (out / "report.html").is_file()

"""``hil recover DIR`` run as a command (docs/reliability.md, "Crash-safe runs").

Why two tests. The rebuild is a function of the folder's hop logs (and its settings and
resolved scenario); a SIGKILLed run's hop logs are never those of any finished run, so the only
exact comparison with the normal path is the same hop logs through both paths:

1. a finished run's folder stripped to what a killed ``hil run`` leaves (its hop logs, settings,
   scenario, PIDs, console logs, and the recording cut inside its summary section; no
   summary.json, trace.csv, series.npz or plot), recovered by the command: every figure, the
   verdict, the trace and the per-sample series equal the finished run's; only what says the
   run was recovered differs;
2. a run really SIGKILLed mid-way (the services die with it: PR_SET_PDEATHSIG), recovered by
   the command: the folder is whole, marked recovered and cut short, and every figure of the
   rebuilt summary.json is the definition evaluated on the hop logs the kill left (the
   calibration tests' own reader, tests/raw_hoplogs.py, not hil.analysis.measure).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from hil.folder import layout
from hil.folder.recording import is_complete, read_messages
from tests.procs import spawned, wait_until
from tests.raw_hoplogs import RawRun, check_summary_against_raw
from tests.run_helpers import BENCH_LATE_OR_PASS, alive, clean_scenario, hil_run

# What a killed hil run does not write (the rest is written before the services start, or
# streamed by them while they run).
WRITTEN_AT_THE_END = (layout.SUMMARY, layout.TRACE, layout.SERIES, layout.TRAJECTORY_PNG)
# What says how the folder was made: the only keys a recovered summary may differ in. hil run
# adds its own facts (hil.bench.lifecycle: wall time, the children's exit codes, the recorder's
# counts, secure), which a recovery cannot know; hil recover adds recovered, note, and cuts
# the duration to what ran.
HOW_MADE = {"interrupted", "error", "bench_error", "wall_time_s", "exit_codes", "recording",
            "recorded_messages", "recorder", "secure", "recovered", "note", "duration"}  # fmt: skip


def _recover(folder: Path) -> dict:
    done = subprocess.run(
        [sys.executable, "-m", "hil", "recover", str(folder)],
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout)


def _cut(recording: Path) -> None:
    """The recording as a killed writer leaves it: its data whole, its summary section cut."""
    size = recording.stat().st_size
    with open(recording, "r+b") as f:
        f.truncate(size - 64)
    assert not is_complete(recording)


def _topics(recording: Path) -> dict[str, int]:
    counts: dict[str, int] = {}
    for m in read_messages(recording):
        counts[m.topic] = counts.get(m.topic, 0) + 1
    return counts


def test_recovering_a_finished_runs_logs_gives_the_finished_runs_folder(tmp_path):
    finished = tmp_path / "finished"
    # What is compared is the two paths, not the verdict: the clean run PASSes, or on a loaded
    # host is INCONCLUSIVE when the bench itself was late (a plant woken past half a period
    # leaves its sample without a command: the verdict's bench share), never FAIL.
    hil_run(finished, str(clean_scenario(tmp_path)), "--duration", "2", expect=BENCH_LATE_OR_PASS)
    killed = tmp_path / "killed"
    killed.mkdir()
    for path in finished.iterdir():
        if path.is_file() and path.name not in WRITTEN_AT_THE_END:
            shutil.copy2(path, killed / path.name)
    _cut(killed / layout.RECORDING)

    done = _recover(killed)
    assert sorted(done["repaired"]) == sorted([layout.TRACE, layout.SUMMARY, layout.RECORDING])
    a = json.loads((finished / layout.SUMMARY).read_text())
    b = json.loads((killed / layout.SUMMARY).read_text())
    assert b["recovered"] is True and b["interrupted"] is True
    differ = {k for k in a.keys() | b.keys() if a.get(k) != b.get(k)}
    assert differ <= HOW_MADE | {"verdict", "duration_run_s"}, differ - HOW_MADE
    assert b["duration_run_s"] == a["duration_run_s"]
    for key in ("timing", "messages", "certificate", "host", "violations", "samples"):
        assert a[key] == b[key], key
    # The verdict is the finished run's; a recovered run only says it was cut short.
    va, vb = a["verdict"], b["verdict"]
    assert {k for k in va if va[k] != vb.get(k)} <= {"notes"}, (va, vb)
    assert [n for n in vb["notes"] if not n.startswith("interrupted")] == va["notes"]
    assert (killed / layout.TRACE).read_bytes() == (finished / layout.TRACE).read_bytes()
    sa, sb = np.load(finished / layout.SERIES), np.load(killed / layout.SERIES)
    assert sorted(sa.files) == sorted(sb.files)
    for name in sa.files:
        assert np.array_equal(sa[name], sb[name]), name
    # The recording: complete again, every message the finished one has.
    assert is_complete(killed / layout.RECORDING)
    assert _topics(killed / layout.RECORDING) == _topics(finished / layout.RECORDING)


def test_a_run_killed_mid_way_is_made_whole_by_the_command(tmp_path):
    out = tmp_path / "run"
    with spawned() as spawn:
        proc = spawn.python(
            ["-m", "hil", "run", "--duration", "3", "--quiet", "--no-report", "--out", str(out)]
        )

        def started() -> bool:
            assert proc.poll() is None, proc.stderr.read().decode(errors="replace")[-2000:]
            try:
                return bool(RawRun.epoch_of(out))
            except (OSError, ValueError, KeyError):
                return False

        assert wait_until(started, 120), "the run never started"
        epoch = RawRun.epoch_of(out)
        time.sleep(max(0.0, (epoch + 1_500_000_000 - time.monotonic_ns()) / 1e9))
        pids = json.loads((out / layout.PROCESSES).read_text())
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        # Its services die with it (PR_SET_PDEATHSIG): wait for them, by PID.
        children = [pids[k] for k in ("controller", "plant")]
        assert wait_until(lambda: not any(alive(p) for p in children), 30), children
    assert not (out / layout.SUMMARY).exists()
    assert not is_complete(out / layout.RECORDING)

    done = _recover(out)
    assert layout.SUMMARY in done["repaired"] and layout.RECORDING in done["repaired"]
    summary = json.loads((out / layout.SUMMARY).read_text())
    assert summary["recovered"] is True and summary["interrupted"] is True
    assert 1.0 < summary["duration_run_s"] < 2.5  # killed at 1.5 s, the logs' last 0.1 s lost
    assert is_complete(out / layout.RECORDING)
    assert (out / layout.TRACE).is_file()
    check_summary_against_raw(summary, RawRun(out))
    assert _recover(out)["repaired"] == []  # whole now: nothing more to do

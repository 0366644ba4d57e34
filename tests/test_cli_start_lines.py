"""Long commands off a terminal (a pipe: a CI log, nohup) say at once what they run, for how
long and where they write, then show progress in plain lines (hil.ticker), on stderr.

Each command runs as a real subprocess with stderr a pipe. The progress interval is set low
(HIL_PROGRESS_INTERVAL_S) so that a short command prints progress too; the ticker's first line
comes at the first progress call, so at least one line is certain however loaded the host.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

S = "paper_tracking"

CASES = [
    (["sim", S, "--duration", "1"], "hil sim", "1 s simulated"),
    (
        ["sweep", S, "--ts", "0.01,0.02", "--delay", "0", "--duration", "0.5"],
        "hil sweep",
        "0.5 s simulated each",
    ),
    (["margin", S, "--seeds", "2", "--duration", "0.5", "--k-max", "2"], "hil margin", "0.5 s"),
    (["run", "--duration", "2", "--no-can", "--no-report"], "hil run", "2 s"),
]


@pytest.mark.parametrize(("argv", "label", "how_long"), CASES, ids=lambda c: str(c)[:12])
def test_a_long_command_says_what_for_how_long_and_where_then_progress(
    tmp_path: Path, argv: list[str], label: str, how_long: str
) -> None:
    out = tmp_path / "out"
    env = dict(os.environ, HIL_PROGRESS_INTERVAL_S="0.2")
    proc = subprocess.run(
        [sys.executable, "-m", "hil", *argv, "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode in (0, 1), proc.stderr[-3000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith(label + ":")]
    assert lines, proc.stderr[-3000:]
    start = lines[0]
    assert how_long in start and str(out) in start and "law unified" in start, start
    assert proc.stderr.splitlines()[0] == start or argv[0] == "margin", proc.stderr[:2000]
    if argv[0] != "margin":  # margin's progress is its line a scale, on stdout
        assert len(lines) >= 2, proc.stderr[-3000:]
    else:
        assert "k = " in proc.stdout, proc.stdout

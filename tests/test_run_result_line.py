"""``hil run`` ends with one plain line: the outcome, why, D against D*, and where the report
is; ``--json`` gives scripts the brief as JSON on stdout and the line on stderr."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.run_helpers import PASSES, check_verdict, clean_scenario

pytestmark = pytest.mark.realtime

LINE = re.compile(r"result: (PASS|FAIL|INCONCLUSIVE): .*; (report|run folder): (\S+)$")


def _run(tmp_path: Path, out: Path, *args: str) -> tuple[subprocess.CompletedProcess[str], dict]:
    """A clean run (CLEAN_50HZ: its verdict is PASS, checked with its exit code)."""
    scenario = clean_scenario(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "run", str(scenario), "--duration", "1", "--quiet",
         "--out", str(out), *args],
        cwd=tmp_path, capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert (out / "summary.json").is_file(), proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    check_verdict(summary, PASSES, proc.returncode, out, context=proc.stderr[-3000:])
    return proc, summary


def test_hil_run_ends_with_one_line_naming_the_outcome_and_the_report(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc, summary = _run(tmp_path, out)
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 1, proc.stdout  # no JSON blob without --json
    m = LINE.fullmatch(lines[0])
    assert m and m.group(2) == "report", lines[0]
    assert Path(m.group(3)) == out / "report.html" and (out / "report.html").is_file()
    assert m.group(1) == summary["verdict"]["outcome"] == "PASS", lines[0]
    d, ds = summary["certificate"]["d_max_s"], summary["certificate"]["d_star_s"]
    assert f"D {d * 1e3:.2f} ms of D* {ds * 1e3:.2f} ms" in lines[0], lines[0]  # said once
    assert "D* = " not in lines[0], lines[0]


def test_hil_run_json_gives_the_brief_on_stdout_and_the_line_on_stderr(tmp_path: Path) -> None:
    out = tmp_path / "run"
    proc, summary = _run(tmp_path, out, "--json", "--no-report")
    brief = json.loads(proc.stdout)
    assert Path(brief["run_dir"]) == out
    assert brief["verdict"] == summary["verdict"]["outcome"] == "PASS", brief
    assert brief["reasons"] == summary["verdict"]["reasons"] == [], brief
    lines = proc.stderr.strip().splitlines()  # the start line (hil.ticker), then the result
    assert lines[0].startswith("hil run: ") and str(out) in lines[0], proc.stderr
    m = LINE.fullmatch(lines[-1])
    assert m and m.group(1) == "PASS" and m.group(2) == "run folder", proc.stderr
    assert Path(m.group(3)) == out, proc.stderr


def test_the_line_quotes_a_long_reason_up_to_its_details_and_d_once() -> None:
    """A bench stall's reason lists every stall: the line keeps its first clause (the report
    has the rest) and does not repeat D against D* after a reason that says it."""
    from hil.commands.run import verdict_line

    stall = (
        "the bench stalled: command age D = 85.690 ms > D* = 20.442 ms on the "
        "zenoh path (margin -65.248 ms; failing: sampled |ω| bound <= φ2) only because the "
        "plant emulator stalled at t = 9.478 s (command age 85.690 ms, plant_late)"
    )
    summary = {
        "verdict": {"outcome": "INCONCLUSIVE", "reasons": [stall + "; " + "another stall; " * 20]},
        "certificate": {"d_max_s": 0.08569, "d_star_s": 0.020442},
    }
    line = verdict_line(summary, "runs/r/report.html")
    assert line.startswith("INCONCLUSIVE: the bench stalled: command age D = ")
    assert line.endswith("; report: runs/r/report.html") and len(line) < 300, line
    assert "another stall" not in line and line.count("D* ") == 1, line
    summary = {
        "verdict": {"outcome": "PASS", "reasons": [], "limits": "held"},
        "certificate": {"d_max_s": 0.0035, "d_star_s": 0.020442},
    }
    line = verdict_line(summary, "runs/r/report.html")
    assert line == "PASS: limits held, D 3.50 ms of D* 20.44 ms; report: runs/r/report.html"

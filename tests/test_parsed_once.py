"""One ``hil run`` parses its scenario once and judges its verdict once: the bench hands its
:class:`hil.scenario.Scenario` down to the analysis and the report (neither re-reads the TOML
into a second one), and the report takes the verdict summary.json holds instead of judging again.

Counted in the real ``hil run`` process (real services, a clean 1 s run) by a profile hook on
the code objects of :func:`hil.scenario.parse_scenario` and :func:`hil.verdict.judge`, so a call
through any imported name counts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.run_helpers import clean_scenario

pytestmark = pytest.mark.realtime

COUNTING = """
import json, sys, threading
from hil.cli import main
from hil.scenario import parse_scenario
from hil.verdict import judge

names = {parse_scenario.__code__: "parses", judge.__code__: "judges"}
counts = {"parses": 0, "judges": 0}

def hook(frame, event, arg):
    if event == "call" and frame.f_code in names:
        counts[names[frame.f_code]] += 1

threading.setprofile(hook)
sys.setprofile(hook)
try:
    code = main(sys.argv[2:])
finally:
    sys.setprofile(None)
    with open(sys.argv[1], "w") as f:
        json.dump(counts, f)
raise SystemExit(code)
"""


def test_one_hil_run_parses_its_scenario_once_and_judges_once(tmp_path: Path) -> None:
    out, counts = tmp_path / "run", tmp_path / "counts.json"
    scenario = clean_scenario(tmp_path)
    argv = ["run", str(scenario), "--duration", "1", "--quiet", "--out", str(out)]
    proc = subprocess.run(
        [sys.executable, "-c", COUNTING, str(counts), *argv],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert counts.is_file(), proc.stderr[-3000:]
    # the report was written (it is where a second parse and a second judgement used to be)
    assert (out / "report.json").is_file(), proc.stderr[-3000:]
    assert json.loads(counts.read_text()) == {"parses": 1, "judges": 1}, proc.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    # the report states the run's own verdict, the one summary.json holds
    assert report["verdict"] == summary["verdict"], (report["verdict"], summary["verdict"])

"""The run report and the result line read as one page: one symbol style
(the paper's, from hil.limits.LIMITS) everywhere, the stall table in one piece, whole result
lines, no "INCONCLUSIVE: inconclusive" headline, and no section for a path that did not run."""

from __future__ import annotations

import copy
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hil.analysis.report.content import render_html, render_markdown
from hil.cli import main
from hil.commands.run import verdict_line
from hil.verdict import INCONCLUSIVE, judge
from tests.run_helpers import clean_scenario
from tests.synthetic_folder import write_synthetic_folder

#: The limits' ASCII spellings that must not show beside the paper's symbols on a page.
ASCII_SYMBOLS = re.compile(r"\b(phi[12]|varpi[12])\b|\|(omega|w|tau[12])\|")


@pytest.fixture(scope="module")
def stall(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run that lost 30 ms of Zenoh commands at t = 2 s: D > D*, a design condition fails."""
    folder = tmp_path_factory.mktemp("stall") / "run"
    write_synthetic_folder(folder, run=True, stall=(2.0, 0.03))
    assert main(["report", str(folder), "--no-ideal"]) == 1
    return folder


def test_the_report_says_each_limit_in_one_symbol_style(tmp_path: Path, stall: Path) -> None:
    """v beyond φ1 (a FAIL whose reason names the limit) and a stall whose certificate fails
    a design condition: the verdict's reasons, the headline and the certificate's conditions
    say φ1, |ω|, never phi1, |omega| (the report said "phi2" beside "φ2")."""
    bad = write_synthetic_folder(tmp_path / "bad", overshoot=1.5)
    assert main(["report", str(bad), "--no-ideal"]) == 1
    for folder in (bad, stall):
        for page in ("report.md", "report.html"):
            text = (folder / page).read_text()
            assert not ASCII_SYMBOLS.search(text), (page, ASCII_SYMBOLS.search(text))
    assert "|v| beyond φ1 = 1.6 m/s" in (bad / "report.md").read_text()
    assert "sampled |ω| bound <= φ2" in (stall / "report.md").read_text()


def test_the_stall_table_is_one_table(stall: Path) -> None:
    """A run with five stalls: one table of five rows (it was split, three and then two)."""
    data = json.loads((stall / "report.json").read_text())
    first = data["certificate"]["stalls"][0]
    data["certificate"]["stalls"] = [
        {**copy.deepcopy(first), "t_s": first["t_s"] + k} for k in range(5)
    ]
    md = render_markdown(data, [])
    assert md.count("| t [s] | age [ms] | cause | evidence |") == 1
    html = render_html(data, [])
    assert html.count("<th>t [s]</th><th>age [ms]</th>") == 1


def test_the_result_line_keeps_a_long_reason_whole() -> None:
    """A first reason of 420 characters without a clause break: quoted whole (it was cut at
    a word within 320 characters, "... at t = (…)")."""
    state = ", ".join(f"s{i} = {i / 7:.6f}" for i in range(30))
    reason = (
        f"the law my_law (my_law:MyLaw) raised ValueError('bad') for the state {state} at t = 2.5 s"
    )
    assert len(reason) > 400
    summary = {"verdict": {"outcome": "FAIL", "reasons": [reason]}, "certificate": {}}
    line = verdict_line(summary, "runs/r/report.html")
    assert line == f"FAIL: {reason}; report: runs/r/report.html", line


def test_a_stall_of_the_bench_is_not_headlined_twice_as_inconclusive() -> None:
    """D > D* only through the plant emulator's stall: INCONCLUSIVE, and its reason says what
    happened, not "inconclusive" again ("INCONCLUSIVE: inconclusive, the bench stalled")."""
    cert = {
        "d_max_s": 0.05,
        "d_star_s": 0.02,
        "d_system_s": 0.005,
        "held": False,
        "path": "zenoh",
        "stalls": [{"t_s": 1.0, "age_s": 0.05, "cause": "plant_late", "owner": "bench"}],
    }
    v = judge({}, {}, cert, {}, {}, None)
    assert v.outcome == INCONCLUSIVE
    summary = {"verdict": v.as_dict(), "certificate": cert}
    line = verdict_line(summary, "runs/r/report.html")
    assert line.startswith("INCONCLUSIVE: the bench stalled: command age D = 50.000 ms"), line
    assert "inconclusive" not in line, line


@pytest.mark.realtime
def test_a_run_without_can_has_no_can_section(tmp_path: Path) -> None:
    """``hil run --no-can``: no "CAN and drives" section, no motor-torque figure, and no pointer
    to that section; a run with its CAN drives keeps it (the synthetic run has CAN counters)."""
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "run", str(clean_scenario(tmp_path)), "--duration", "1",
         "--no-can", "--no-report", "--quiet", "--out", str(out)],
        cwd=tmp_path, capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert (out / "summary.json").is_file(), proc.stderr[-3000:]
    main(["report", str(out), "--no-ideal"])
    md, html = (out / "report.md").read_text(), (out / "report.html").read_text()
    assert "CAN and drives" not in md and "CAN and drives" not in html
    assert 'id="drives"' not in html and not (out / "report_motor_torques.png").exists()
    can = write_synthetic_folder(tmp_path / "can", run=True, delay=0.0005, duration=2.0)
    assert main(["report", str(can), "--no-ideal"]) == 0
    assert "## CAN and drives" in (can / "report.md").read_text()


def test_hil_report_keeps_the_verdict_the_analysis_judged(tmp_path):
    """The verdict is judged once: hil report on a folder whose summary.json holds one shows
    that one (a run's report said FAIL where hil run had said PASS, with the drives' figures
    read differently); with other thresholds asked it judges again."""
    import json
    import subprocess
    import sys

    out = tmp_path / "run"
    subprocess.run(
        [sys.executable, "-m", "hil", "run", "--duration", "2", "--no-report", "--quiet",
         "--out", str(out)],
        capture_output=True, timeout=300,
    )  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())
    planted = "a reason only the analysis gave"
    summary["verdict"] = {**summary["verdict"], "outcome": "FAIL", "ok": False,
                          "fail_reasons": [planted], "inconclusive_reasons": [],
                          "reasons": [planted]}  # fmt: skip
    (out / "summary.json").write_text(json.dumps(summary))
    p = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out), "--no-ideal"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 1, p.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["verdict"]["reasons"] == [planted]

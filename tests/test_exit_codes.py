"""One exit code per verdict, for every command (hil.verdict.EXIT_CODE; docs/reports.md, "Verdict
and exit code"): PASS 0, FAIL 1 whatever made it, INCONCLUSIVE 4, bad input 2, interrupted 130.

On c20de4f ``hil report`` exited 1 for INCONCLUSIVE, ``hil run`` 0 for INCONCLUSIVE and for a
FAIL from missed slots or samples without a command (only "blocking" FAILs exited 1, and
``--strict`` made INCONCLUSIVE 1), and the report said "the bench stalled, not your system"
under a FAIL. Folders are synthetic (tests/synthetic_folder.py: hop logs measured by
hil.analysis.measure, as ``hil run`` writes them); an INCONCLUSIVE one is the command-loss stall
whose summary names the stall the plant's (the report reads summary.json's certificate), so the
verdict is known by construction whatever hil.analysis.measure.stalls decides.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from hil.cli import main
from hil.verdict import BENCH_ADVICE, EXIT_CODE, FAIL, INCONCLUSIVE, PASS, judge
from tests.synthetic_folder import write_synthetic_folder

HIL = [sys.executable, "-m", "hil"]


def _edit_summary(folder: Path, change) -> None:
    path = folder / "summary.json"
    s = json.loads(path.read_text())
    change(s)
    path.write_text(json.dumps(s, indent=2))


def _bench_owned(s: dict[str, Any]) -> None:
    """The stall that pushed D past D* becomes the plant emulator's (the bench's)."""
    cert = s["certificate"]
    for st in cert["stalls"]:
        st.update(cause="plant_late", owner="bench")
    cert["d_system_s"] = min(cert["d_star_s"], 0.004)


def _bench_stall_beside(s: dict[str, Any]) -> None:
    """A stall of the bench, listed beside the system's own (which stays)."""
    cert = s["certificate"]
    worst = cert["stalls"][0]
    bench = {**worst, "t_s": worst["t_s"] + 1.0, "cause": "plant_late", "owner": "bench"}
    cert["stalls"].append(bench)


@pytest.fixture(scope="module")
def folders(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("verdicts")
    clean = write_synthetic_folder(root / "pass", run=True, delay=0.0005)
    fail = write_synthetic_folder(root / "fail", run=True, stall=(2.0, 0.03))
    unsure = root / "inconclusive"
    shutil.copytree(fail, unsure)
    _edit_summary(unsure, _bench_owned)
    both = root / "fail_beside_bench"
    shutil.copytree(fail, both)
    _edit_summary(both, _bench_stall_beside)
    return {PASS: clean, FAIL: fail, INCONCLUSIVE: unsure, "both": both}


@pytest.mark.parametrize("outcome", [PASS, FAIL, INCONCLUSIVE])
def test_hil_report_exits_with_its_verdicts_code(folders, outcome):
    folder = folders[outcome]
    proc = subprocess.run(
        [*HIL, "report", str(folder), "--no-ideal"], capture_output=True, text=True
    )
    verdict = json.loads((folder / "report.json").read_text())["verdict"]
    assert verdict["outcome"] == outcome, verdict["reasons"]
    assert proc.returncode == EXIT_CODE[outcome] == {PASS: 0, FAIL: 1, INCONCLUSIVE: 4}[outcome]
    if outcome != PASS:  # the outcome and its reason on stderr, for a script's log
        assert f"verdict: {outcome}: " in proc.stderr, proc.stderr[-2000:]


def test_the_bench_advice_is_on_the_page_only_under_inconclusive(folders):
    """The bench stalled, not your system": under INCONCLUSIVE only, never beside a FAIL (the
    FAIL folder with a bench stall listed beside the system's own)."""
    for name, want in ((INCONCLUSIVE, True), ("both", False), (FAIL, False), (PASS, False)):
        folder = folders[name]
        main(["report", str(folder), "--no-ideal"])
        data = json.loads((folder / "report.json").read_text())
        md = (folder / "report.md").read_text()
        assert (data["verdict"]["advice"] == [BENCH_ADVICE]) is want, (name, data["verdict"])
        assert ("the bench stalled, not your system" in md) is want, name
        if name == "both":
            assert data["verdict"]["outcome"] == FAIL


def _summary(verdict_of: str, **extra: Any) -> dict[str, Any]:
    """A run's summary whose verdict is ``verdict_of`` (hil.verdict.judge on its figures)."""
    cert = {"path": "zenoh", "d_max_s": 0.003, "d_star_s": 0.0204, "held": True, "stalls": []}
    timing: dict[str, Any] = {}
    if verdict_of == "misses":  # FAIL by missed slots alone (c20de4f: exit 0)
        timing = {"deadline_misses": 40, "slots": 2000, "deadline_miss_rate": 0.02}
    if verdict_of == INCONCLUSIVE:
        stall = {"t_s": 2.0, "age_s": 0.043, "cause": "plant_late", "owner": "bench"}
        cert.update(d_max_s=0.043, held=False, d_system_s=0.0035, stalls=[stall])
    v = judge({}, {}, cert, timing, {}, None)
    return {"kind": "run", "run_dir": "runs/x", "verdict": v.as_dict(), "certificate": cert,
            "timing": timing, **extra}  # fmt: skip


def _run_gives(monkeypatch: pytest.MonkeyPatch, summary: dict[str, Any]) -> None:
    """``hil run``'s two wings replaced: the bench records nothing (its folder is the summary's
    run_dir), the analysis gives ``summary``."""
    import hil.analysis.analyze as analyze
    import hil.bench.lifecycle as lifecycle

    recorded = SimpleNamespace(run_dir=Path(summary["run_dir"]))
    monkeypatch.setattr(lifecycle, "execute", lambda opts: recorded)
    monkeypatch.setattr(analyze, "write_results", lambda rec: summary)


@pytest.mark.parametrize(
    ("verdict_of", "code"), [(PASS, 0), ("misses", 1), (INCONCLUSIVE, 4)]
)  # fmt: skip
@pytest.mark.parametrize("strict", [False, True])
def test_hil_run_exits_with_its_verdicts_code_and_strict_changes_nothing(
    monkeypatch, tmp_path, verdict_of, code, strict
):
    """``hil run`` end to end through the CLI, its run replaced by a summary of known verdict:
    FAIL from missed slots alone exits 1, INCONCLUSIVE 4, with or without --strict."""
    _run_gives(monkeypatch, _summary(verdict_of))
    argv = ["run", "--no-report", "--quiet", "--out", str(tmp_path / "run")]
    assert main([*argv, *(["--strict"] if strict else [])]) == code


def test_hil_run_strict_says_it_changes_nothing():
    proc = subprocess.run([*HIL, "run", "--help"], capture_output=True, text=True)
    # the words of the help, without the table's borders (a wrapped cell splits a sentence)
    help_text = " ".join(w for w in proc.stdout.split() if w not in ("│", "││"))
    assert "--strict" in help_text and "changes nothing" in help_text, help_text


def test_the_fleets_verdict_is_its_robots_and_its_exit_code_follows(tmp_path):
    """hil fleet: FAIL when a robot FAILs (or left no verdict), else INCONCLUSIVE when one is,
    else PASS; the miss rate over the robots' slots, as each robot's (c20de4f: over ticks)."""
    from hil.analysis import fleet_report as report

    def robot(name: str, outcome: str | None, misses: int = 0) -> None:
        folder = tmp_path / name
        folder.mkdir()
        if outcome is None:
            return  # a run that left no summary
        timing = {"deadline_misses": misses, "ticks": 485, "slots": 500,
                  "samples_without_command": 0, "samples_judged": 498}  # fmt: skip
        folder.joinpath("summary.json").write_text(
            json.dumps({"verdict": {"outcome": outcome}, "timing": timing, "certificate": {}})
        )

    robot("robot1", PASS, misses=15)
    robot("robot2", INCONCLUSIVE)
    s = report.fleet_summary(tmp_path, {"robot1": 0, "robot2": 4}, {})
    assert (s["fleet"]["verdict"], s["fleet"]["verdict_robots"]) == (INCONCLUSIVE, ["robot2"])
    assert s["fleet"]["deadline_miss_rate"] == 15 / 1000  # 15 missed of 2 x 500 slots
    assert "Verdict: INCONCLUSIVE (robots INCONCLUSIVE: robot2; none FAIL)." in report.markdown(s)
    robot("robot3", FAIL)
    robot("robot4", None)
    codes = {"robot1": 0, "robot2": 4, "robot3": 1, "robot4": 3}
    s = report.fleet_summary(tmp_path, codes, {})
    assert (s["fleet"]["verdict"], s["fleet"]["verdict_robots"]) == (FAIL, ["robot3", "robot4"])
    assert EXIT_CODE[s["fleet"]["verdict"]] == 1
    robots = [tmp_path / "all_pass" / f"robot{i}" for i in (1, 2)]
    for folder in robots:
        folder.mkdir(parents=True)
        folder.joinpath("summary.json").write_text(json.dumps({"verdict": {"outcome": PASS}}))
    s = report.fleet_summary(tmp_path / "all_pass", {"robot1": 0, "robot2": 0}, {})
    assert s["fleet"]["verdict"] == PASS and EXIT_CODE[PASS] == 0


def test_the_sweeps_verdict_is_not_its_break_point():
    """The break point is the sweep's answer (PASS, exit 0); a law that faulted in a loop is
    a FAIL; --strict makes any broken limit a FAIL."""
    from hil.sweep.grid import sweep_outcome

    rows = [{"violation": False}, {"violation": True}]
    assert sweep_outcome(rows, strict=False) == (PASS, "")
    assert sweep_outcome(rows, strict=True)[0] == FAIL
    faulted = [*rows, {"violation": False, "law_fault": {"law": "nan_law"}}]
    outcome, why = sweep_outcome(faulted, strict=False)
    assert outcome == FAIL and why == "the law faulted in 1 of 3 loops"


def test_a_run_stopped_by_its_own_error_says_fail_and_exits_1(monkeypatch, tmp_path, capsys):
    """The result line is the exit's outcome: a run whose outside device never came is a
    FAIL (exit 1), said first, whatever its figures' verdict."""
    _run_gives(monkeypatch, _summary(PASS, error="no device connected within 5 s"))
    argv = ["run", "--no-report", "--quiet", "--out", str(tmp_path / "run")]
    assert main(argv) == 1
    said = capsys.readouterr()
    assert "result: FAIL: no device connected within 5 s" in said.out
    assert "verdict: FAIL: no device connected within 5 s" in said.err


def test_the_bench_says_which_service_kept_the_run_from_starting() -> None:
    """hil.bench.lifecycle.NotReady: the service that ended first (its code and its log,
    beside a fleet group's folder too), else those still starting, else the stop."""
    from hil.bench.lifecycle import NotReady

    ended = NotReady(("plant",), {"plant": 1}, 2.5, False)
    assert ended.sentence(" of robot2", "../robot1-group-") == (
        "the bench did not start the run of robot2: the plant exited with code 1 before it was "
        "ready (its output: ../robot1-group-plant.log)"
    )
    slow = NotReady(("controller",), {}, 300.0, False)
    assert slow.sentence() == (
        "the bench did not start the run: the controller did not say ready within 300 s (still "
        "starting: a host too slow or too busy; output: controller.log)"
    )
    stopped = NotReady(("plant", "controller"), {}, 1.0, True)
    said = "the bench did not start the run: stopped while its services started"
    assert stopped.sentence() == said

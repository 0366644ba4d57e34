"""``hil fleet``: N closed loops at once, each robot on its own keys with its own run folder,
over loopback and across two lab hosts through shared routers; the fleet report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.folder.rates import RATES
from hil.folder.recording import read_messages
from hil.verdict import EXIT_CODE
from tests.lab_helpers import ROOT, lab, lab_name, lab_skip_reason
from tests.run_helpers import (
    BENCH_LATE_OR_PASS,
    LOADED_HOST,
    PASSES,
    check_fleet,
    check_verdict,
    clean_scenario,
    fleet_outcome,
)


def _fleet(
    out: Path, robots: int, *extra: str, loaded: bool = False
) -> subprocess.CompletedProcess:
    """``hil fleet`` of clean runs at 100 Hz (CLEAN_50HZ, --rate 100: D* = 498 ms, 50
    periods): every robot's verdict is PASS, or INCONCLUSIVE when only the bench's host stopped
    (``loaded``: or what a loaded host does that the
    robot's own logs explain, LOADED_HOST), and the fleet's exit code that of its robots'."""
    scenario = str(clean_scenario(out.parent))
    args = [scenario, "--robots", str(robots), "--duration", "2", "--rate", "100"]
    done = subprocess.run(
        [sys.executable, "-m", "hil", "fleet", *args, "--out", str(out), *extra],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    check_fleet(out, robots, done, (PASSES, *LOADED_HOST) if loaded else BENCH_LATE_OR_PASS)
    return done


def _check_robot_folders(out: Path, robots: int) -> dict:
    fleet = json.loads((out / "fleet.json").read_text())
    assert [r["robot"] for r in fleet["per_robot"]] == [f"robot{i}" for i in range(1, robots + 1)]
    for row in fleet["per_robot"]:
        folder = out / row["robot"]
        settings = json.loads((folder / "run_settings.json").read_text())
        assert settings["robot_id"] == row["robot"]
        # Its own keys only, and its own loop closed: commands sent and received.
        topics = {m.topic for m in read_messages(folder / "recording.mcap")}
        assert topics and all(t.startswith(f"hil/{row['robot']}/") for t in topics), topics
        summary = json.loads((folder / "summary.json").read_text())
        torque = summary["messages"]["torque_zenoh"]
        assert torque["sent"] > 100 and torque["received"] >= 0.95 * torque["sent"], torque
        assert row["d_max_s"] == summary["certificate"]["d_max_s"]
    assert (out / "fleet.md").read_text().startswith(f"# Fleet of {robots} robots")
    assert (out / "fleet.png").stat().st_size > 0
    return fleet


def test_a_fleet_over_loopback_gives_each_robot_its_own_loop_and_folder(tmp_path):
    out = tmp_path / "fleet"
    done = _fleet(out, 2)
    fleet = _check_robot_folders(out, 2)
    assert fleet["fleet"]["robots"] == 2
    # The aggregates are the robots' own figures pooled by the one rule (hil.folder.rates), and
    # the exit code is the fleet's verdict's (hil.verdict.EXIT_CODE).
    summaries = [json.loads((out / f"robot{i}" / "summary.json").read_text()) for i in (1, 2)]
    for rate, (count, over) in RATES.items():
        robots = [s["timing"] for s in summaries if rate in s["timing"]]
        if not robots:
            continue
        total = sum(t[over] for t in robots)
        assert fleet["fleet"][rate] == sum(t[count] for t in robots) / total, rate
    outcomes = [s["verdict"]["outcome"] for s in summaries]
    assert [r["verdict"] for r in fleet["per_robot"]] == outcomes
    want = fleet_outcome(outcomes)
    assert fleet["fleet"]["verdict"] == want
    assert done.returncode == EXIT_CODE[want], (want, done.stderr[-2000:])
    p99 = sorted(s["timing"]["command_age_zenoh"]["p99_us"] for s in summaries)
    assert (
        fleet["fleet"]["command_age_p99_us_max"],
        fleet["fleet"]["command_age_p99_us_median"],
    ) == (p99[1], p99[0])
    # Each robot's report, written by hil fleet itself (no `hil report` by hand), with the
    # verdict its run judged; the fleet's page links each.
    for i, s in enumerate(summaries, 1):
        folder = out / f"robot{i}"
        assert (folder / "report.html").is_file()
        assert json.loads((folder / "report.json").read_text())["verdict"] == s["verdict"]
        assert f'href="robot{i}/report.html"' in (out / "fleet.html").read_text()
    # Each robot's folder is a complete run folder: hil report reads it.
    report = subprocess.run(
        [sys.executable, "-m", "hil", "report", str(out / "robot2")],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    judged = json.loads((out / "robot2" / "report.json").read_text())
    check_verdict(judged, BENCH_LATE_OR_PASS, report.returncode, out / "robot2", command="report")
    assert (out / "robot2" / "report.html").is_file()


@pytest.mark.skipif(lab_skip_reason() is not None, reason=lab_skip_reason() or "")
def test_a_four_robot_fleet_across_two_lab_hosts(tmp_path):
    out = tmp_path / "fleet"
    with lab(lab_name("f"), "--hosts", "2") as name:
        # Through two routers on a loaded host a State or two of 199 may come after its tick
        # (1.005 % > 1 %, CI): each count explained by the robot's own logs.
        _fleet(out, 4, "--lab", name, "--plant-host", "h1", "--controller-host", "h2",
               loaded=True)  # fmt: skip
    _check_robot_folders(out, 4)
    for i in range(1, 5):
        topo = json.loads((out / f"robot{i}" / "topology.json").read_text())
        assert topo["processes"]["controller"] == "h2" and topo["clock"]["converted"]

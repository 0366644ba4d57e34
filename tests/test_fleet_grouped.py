"""``hil fleet --per-process K``: K robots' plants in one plant process and their controllers
in one controller process, each robot still on its own keys with its own state, deadlines and
complete run folder."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.bench.lifecycle import phase_ns
from hil.folder.recording import read_messages
from protocol.errors import BadInputError
from protocol.hoplog import read_hoplog
from protocol.settings import RunSettings
from runtime.group import check_group
from tests.lab_helpers import ROOT, lab, lab_name, lab_skip_reason
from tests.run_helpers import (
    BENCH_LATE_OR_PASS,
    LOADED_HOST,
    PASSES,
    check_fleet,
    check_verdict,
    clean_scenario,
)

ROBOTS, PER_PROCESS, RATE = 4, 2, 100


def _hil(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hil", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("grouped") / "fleet"
    scenario = str(clean_scenario(out.parent))
    args = [scenario, "--robots", str(ROBOTS), "--per-process", str(PER_PROCESS)]
    done = _hil("fleet", *args, "--duration", "2", "--rate", str(RATE), "--out", str(out))
    # clean runs at 100 Hz (CLEAN_50HZ: D* = 498 ms), sharing processes or not: PASS, or
    # INCONCLUSIVE when only the bench's host stopped (CI: steal 35 %, both services 30 ms late
    # together), never FAIL
    check_fleet(out, ROBOTS, done, BENCH_LATE_OR_PASS)
    return out


def test_four_robots_run_in_two_plant_and_two_controller_processes(fleet: Path) -> None:
    pids = [json.loads((fleet / f"robot{i}" / "processes.json").read_text()) for i in (1, 2, 3, 4)]
    assert pids[0] == pids[1] and pids[2] == pids[3]  # robots 1, 2 share their processes
    assert set(pids[0].values()).isdisjoint(pids[2].values())  # robots 3, 4 have others
    assert len({p for row in pids for p in row.values()}) == 4  # not 2 N = 8
    summary = json.loads((fleet / "robot2" / "summary.json").read_text())
    assert summary["shared_processes"]["robots"] == ["robot1", "robot2"]
    rows = json.loads((fleet / "fleet.json").read_text())["per_robot"]
    assert [r["robot"] for r in rows] == [f"robot{i}" for i in range(1, ROBOTS + 1)]


def test_each_robot_closes_its_own_loop_on_its_own_keys(fleet: Path) -> None:
    for i in range(1, ROBOTS + 1):
        robot, folder = f"robot{i}", fleet / f"robot{i}"
        # Everything that travelled on this robot's keys is this robot's: no message of its
        # process neighbour (robot 2 for robot 1) was put on them.
        msgs = list(read_messages(folder / "recording.mcap"))
        assert msgs and all(m.topic.startswith(f"hil/{robot}/") for m in msgs)
        ids = {m.data["robot_id"] for m in msgs if "robot_id" in m.data}
        assert ids == {robot}, ids
        # Its plant received its own controller's commands only: no command refused as
        # another robot's, never more received than its controller sent, none lost.
        plant = read_hoplog(folder / "plant.hoplog").final
        ctrl = read_hoplog(folder / "controller.hoplog").final
        assert "wrong_robot" not in plant["rejections"]
        got = plant["cmd_counts"]
        assert got["received"] <= ctrl["commands_sent"], (got, ctrl["commands_sent"])
        # Another robot's command stream (its own numbering) would show as duplicates and
        # reorderings in this one's.
        assert got["duplicated"] == 0 and got["reordered"] == 0, got
        # The loop closed: the commands sent while the plant ran reached it.
        summary = json.loads((folder / "summary.json").read_text())
        torque = summary["messages"]["torque_zenoh"]
        assert torque["sent"] > 100 and torque["received"] >= 0.95 * torque["sent"], torque


def test_each_robot_keeps_its_own_deadlines_interleaved(fleet: Path) -> None:
    """Each robot has its own epoch (its deadlines): robot I's is shifted by (I - 1) / N of a
    period from robot 1's, within a group exactly, so the group's ticks do not all fall due
    at once; the controller keeps the plant's epoch (one host, one clock)."""
    period = round(1e9 / RATE)
    epochs = []
    for i in range(1, ROBOTS + 1):
        plant = read_hoplog(fleet / f"robot{i}" / "plant.hoplog").meta["epoch_ns"]
        assert read_hoplog(fleet / f"robot{i}" / "controller.hoplog").meta["epoch_ns"] == plant
        epochs.append(plant)
    assert epochs[1] - epochs[0] == period // ROBOTS
    assert epochs[3] - epochs[2] == period // ROBOTS


def test_a_grouped_robots_folder_is_a_complete_run_folder(fleet: Path) -> None:
    done = _hil("report", str(fleet / "robot2"), "--no-ideal")
    data = json.loads((fleet / "robot2" / "report.json").read_text())
    check_verdict(data, BENCH_LATE_OR_PASS, done.returncode, fleet / "robot2", command="report")
    assert "latency" in data["sections"] and data["certificate"]["d_max_s"] > 0


def test_phases_spread_the_fleet_over_a_period() -> None:
    shifts = [phase_ns(f"robot{i}", 0, 4, 10_000_000) for i in range(1, 5)]
    assert shifts == [0, 2_500_000, 5_000_000, 7_500_000]
    assert phase_ns("arm", 3, 4, 10_000_000) == 7_500_000  # no number: its position


def test_one_process_refuses_robots_that_cannot_share_it() -> None:
    a = RunSettings(robot_id="robot1", zenoh_endpoint="tcp/127.0.0.1:20001")
    b = RunSettings(robot_id="robot2", zenoh_endpoint="tcp/127.0.0.1:20002")
    with pytest.raises(BadInputError, match="zenoh_endpoint"):
        check_group([a, b])
    with pytest.raises(BadInputError, match="twice"):
        check_group([a, a])
    check_group([a, RunSettings(robot_id="robot2", zenoh_endpoint="tcp/127.0.0.1:20001")])


@pytest.mark.skipif(lab_skip_reason() is not None, reason=lab_skip_reason() or "")
def test_a_grouped_fleet_across_two_lab_hosts(tmp_path: Path) -> None:
    """Two robots per process, plants on h1 and controllers on h2 whose clocks differ: every
    robot's loop closes through the two routers, each controller relates its own clock."""
    out = tmp_path / "fleet"
    scenario = str(clean_scenario(tmp_path))
    with lab(lab_name("g"), "--hosts", "2", "--offset=h2=-1.7") as name:
        args = [scenario, "--robots", "4", "--per-process", "2", "--lab", name]
        args += ["--plant-host", "h1", "--controller-host", "h2", "--duration", "2"]
        done = _hil("fleet", *args, "--rate", str(RATE), "--out", str(out))
    # Through two routers on a loaded host a State or two of 199 may come after its tick
    # (1.005 % > 1 %, CI): each count explained by the robot's own logs.
    check_fleet(out, 4, done, (PASSES, *LOADED_HOST))
    for i in range(1, 5):
        folder = out / f"robot{i}"
        topo = json.loads((folder / "topology.json").read_text())
        assert topo["processes"]["controller"] == "h2" and topo["clock"]["converted"]
        summary = json.loads((folder / "summary.json").read_text())
        torque = summary["messages"]["torque_zenoh"]
        assert torque["sent"] > 100 and torque["received"] >= 0.95 * torque["sent"], torque
    pids = [json.loads((out / f"robot{i}" / "processes.json").read_text()) for i in (1, 2)]
    assert pids[0] == pids[1]

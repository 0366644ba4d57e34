"""One options record from the command line to the services: ``hil run``'s command line is
read into :class:`hil.bench.prepare.RunOptions` by name, and ``RunOptions.argv`` writes it
back (a fleet starts one ``hil run`` per robot from it); a fleet's group carries it as JSON."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import typer.main

from hil.bench.fleet.spawner import FleetOptions, group_argv, run_argv
from hil.bench.group import GroupSpec
from hil.bench.prepare import RunOptions
from hil.cli import app
from hil.commands.run import run_options


def _read_back(argv: list[str]) -> RunOptions:
    """``hil run ARGV`` parsed by hil run's own command line, into the options record."""
    command = typer.main.get_command(app).commands["run"]  # type: ignore[attr-defined]
    ctx = command.make_context("run", list(argv))
    return run_options(dict(ctx.params), RunOptions)


def test_argv_is_read_back_into_the_same_options() -> None:
    opts = RunOptions(
        scenario=Path("my.toml"),
        duration=2.5,
        rate=100.0,
        cmd_path="can",
        out=Path("runs/x"),
        trigger="on_state",
        can_live=False,
        can_interface="virtual",
        can_channel="ch0",
        spin_us=50.0,
        quiet=True,
        live_port=8765,
        live_host="0.0.0.0",
        law="my_law:MyLaw",
        robot_id="robot7",
        force=True,
        wait_device=12.0,
        zenoh_endpoint="tcp/127.0.0.1:23456",
        can_endpoint="tcp/127.0.0.1:23457",
    )
    assert _read_back(opts.argv()) == opts
    # defaults write nothing but the scenario, and read back as defaults
    assert RunOptions(scenario=Path("s.toml")).argv() == ["s.toml"]
    assert _read_back(["s.toml"]) == RunOptions(scenario=Path("s.toml"))
    # the booleans that default to on and off both come back
    flags = RunOptions(lockstep=True, secure=True, can_live=False).argv()
    assert flags == ["--lockstep", "--no-can", "--secure"]
    assert _read_back(flags) == RunOptions(lockstep=True, secure=True, can_live=False)


def test_a_field_hil_run_has_no_option_for_is_refused_not_dropped() -> None:
    with pytest.raises(ValueError, match="no option for scheduling"):
        RunOptions(scheduling="fifo").argv()
    with pytest.raises(ValueError, match="no option for fresh_out"):
        RunOptions(fresh_out=False).argv()


def test_a_fleet_robot_and_a_group_get_the_fleet_s_options(tmp_path: Path) -> None:
    run = RunOptions(scenario=Path("s.toml"), duration=3.0, rate=50.0, law="my_law:MyLaw")
    fleet = FleetOptions(run, robots=3, out=tmp_path, per_process=2)
    argv = run_argv(fleet, "robot2")
    assert argv[argv.index("run") + 1 :] == [
        "s.toml", "--duration", "3.0", "--rate", "50.0", "--out", str(tmp_path / "robot2"),
        "--no-can", "--quiet", "--law", "my_law:MyLaw", "--robot-id", "robot2", "--no-report",
    ]  # fmt: skip
    assert _read_back(argv[argv.index("run") + 1 : -1]) == fleet.robot("robot2")
    spec = GroupSpec.read(Path(group_argv(fleet, ["robot1", "robot2"])[-1]))
    assert (spec.robots, spec.out, spec.fleet_size) == (["robot1", "robot2"], tmp_path, 3)
    # a robot of a group runs with the options a robot of its own hil run would have
    assert spec.options("robot2") == fleet.robot("robot2")
    assert dataclasses.replace(spec.options(), robot_id="robot1") == dataclasses.replace(
        fleet.robot("robot1"), out=None
    )


def test_json_keeps_paths_and_refuses_a_reader() -> None:
    opts = RunOptions(scenario=Path("a/s.toml"), out=Path("runs/y"), duration=1.0)
    assert RunOptions.from_json(opts.to_json()) == opts
    with pytest.raises(ValueError, match="run_latencies"):
        RunOptions(run_latencies=lambda *a: None).to_json()  # type: ignore[arg-type]

"""Scenario files: defaults, refusals naming the key (exit 2), design bounds, round trip."""

from __future__ import annotations

import tomllib
from dataclasses import asdict
from pathlib import Path

import pytest

from controller_service.laws.base import Limits
from hil.bench.prepare import RunOptions, prepare
from hil.bundled import bundled_dir
from hil.cli import main
from hil.errors import BadInputError
from hil.provenance import dumps_toml
from hil.scenario import (
    FaultsConfig,
    ImpairConfig,
    build_loop,
    build_reference,
    design_context,
    load_scenario,
    loads_scenario,
    parse_scenario,
    resolved_dict,
    scenario_dict,
)
from protocol.settings import RunSettings

SCENARIOS = sorted(bundled_dir().glob("*.toml"))
MINIMAL = '[reference]\nkind = "circle"\n[initial]\nx = -1.0\n'


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_shipped_scenarios_load_and_build(path: Path) -> None:
    sc = load_scenario(path)
    controller, reference, context = build_loop(sc)
    assert controller.update is not None and reference.sample(0.0) is not None
    assert context.limits == Limits()


def test_defaults_are_the_papers_setup() -> None:
    sc = loads_scenario(MINIMAL)
    assert sc.limits == Limits(1.6, 5.1, 3.3, 51.0)
    assert sc.timing.ts == 0.001 and sc.plant_step == pytest.approx(1e-4) and sc.substeps == 10
    assert sc.disturbance.kind == "none" and sc.controller["law"] == "unified"
    ctx = design_context(sc, build_reference(sc))
    assert (ctx.mu1, ctx.mu2, ctx.s1, ctx.s2) == (0.5, 0.2, 0.0, 0.0)


@pytest.mark.parametrize(
    ("text", "named"),
    [
        (MINIMAL + "[limits]\nphi3 = 1.0\n", "phi3"),
        (MINIMAL + "[limts]\nphi1 = 1.0\n", "limts"),
        (MINIMAL + '[limits]\nphi1 = "fast"\n', "[limits] phi1"),
        (MINIMAL + "[limits]\nphi1 = -1.0\n", "[limits] phi1"),
        (MINIMAL + "[timing]\nts = 0\n", "[timing] ts"),
        (MINIMAL + '[timing]\njitter_kind = "gauss"\n', "[timing] jitter_kind"),
        (MINIMAL + '[disturbance]\nkind = "constant"\nvalue1 = 0.5\ns1 = 0.1\n', "s1"),
        (MINIMAL + "[plant]\nnoise_std = [0.1, 0.1]\n", "[plant] noise_std"),
        (MINIMAL + "[timing]\nseed = 1.5\n", "[timing] seed"),
        ("[initial]\nx = 1.0\n", "[reference]"),
        ('[reference]\nkind = "circle"\n', "[initial]"),
        ('[reference]\nkind = "circle"\nspeed = 2\n[initial]\n', "speed"),
        (MINIMAL + "[controller]\nlam = 100.0\n", "(11)"),
    ],
)
def test_bad_scenarios_are_refused_naming_the_key(text: str, named: str) -> None:
    with pytest.raises(BadInputError, match=None) as info:
        sc = loads_scenario(text)
        build_loop(sc)
    assert named in str(info.value)


def test_cli_exits_2_naming_the_key(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(MINIMAL + "[timing]\nts = 0.001\ndelya = 0.01\n")
    assert main(["sim", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "delya" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()
    assert main(["sim", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "o")]) == 2


def test_design_bounds_default_to_the_reference_and_must_cover_it() -> None:
    sc = loads_scenario('[reference]\nkind = "circle"\nvd = 0.4\nwd = 0.1\nmu1 = 0.45\n[initial]\n')
    ctx = design_context(sc, build_reference(sc))
    assert ctx.mu1 == 0.45 and ctx.mu2 == pytest.approx(0.1)
    sc = loads_scenario('[reference]\nkind = "circle"\nvd = 0.4\nmu1 = 0.3\n[initial]\n')
    with pytest.raises(BadInputError, match="mu1"):
        design_context(sc, build_reference(sc))


def test_resolved_dict_round_trips_with_auto_resolved(tmp_path: Path) -> None:
    sc = loads_scenario(
        MINIMAL + '[controller]\nlam = "auto"\nrho = "auto"\n'
        '[zenoh]\nendpoints = ["tcp/127.0.0.1:7447"]\n',
        tmp_path,
    )
    controller, _, ctx = build_loop(sc)
    resolved = resolved_dict(sc, controller, ctx)
    text = dumps_toml(resolved)
    data = tomllib.loads(text)
    assert isinstance(data["controller"]["lam"], float) and isinstance(
        data["controller"]["rho"], float
    )
    assert data["provenance"]["package_version"] and "start_time" in data["provenance"]
    assert data["provenance"]["seeds"] == {"timing": 0, "disturbance": 0, "sensor": 0}
    again = parse_scenario(data, tmp_path)
    assert scenario_dict(again)["limits"] == scenario_dict(sc)["limits"]
    assert again.zenoh.endpoints == ("tcp/127.0.0.1:7447",)
    assert build_loop(again)[0].resolved_table()["lam"] == data["controller"]["lam"]


def test_faults_default_to_off() -> None:
    sc = loads_scenario(MINIMAL)
    assert sc.faults == FaultsConfig()
    assert (sc.faults.state_drop_every, sc.faults.command_drop_every, sc.faults.seed) == (0, 0, 0)
    assert scenario_dict(sc)["faults"] == asdict(FaultsConfig())
    assert all(v == 0 for v in scenario_dict(sc)["faults"].values())


def test_faults_round_trip_through_the_resolved_dict(tmp_path: Path) -> None:
    sc = loads_scenario(
        MINIMAL + "[faults]\nstate_drop_every = 7\ncommand_drop_every = 11\n", tmp_path
    )
    assert sc.faults == FaultsConfig(state_drop_every=7, command_drop_every=11, seed=0)
    controller, _, ctx = build_loop(sc)
    data = tomllib.loads(dumps_toml(resolved_dict(sc, controller, ctx)))
    assert data["faults"] == asdict(FaultsConfig(state_drop_every=7, command_drop_every=11))
    assert parse_scenario(data, tmp_path).faults == sc.faults


@pytest.mark.parametrize(
    ("table", "named"),
    [
        ("state_drop_every = -1\n", "[faults] state_drop_every"),
        ("command_drop_every = -3\n", "[faults] command_drop_every"),
        ("seed = -1\n", "[faults] seed"),
        ("state_drop_every = 2.5\n", "[faults] state_drop_every"),
        ("command_drop_every = 2.0\n", "[faults] command_drop_every"),
        ("command_drop_every = true\n", "[faults] command_drop_every"),
        ('seed = "x"\n', "[faults] seed"),
        ("state_drop_evry = 3\n", "state_drop_evry"),
        ("can_frame_loss = 1.5\n", "[faults] can_frame_loss"),
        ("delay_burst_every = 1.0\ndelay_burst_length = 2.0\n", "[faults] delay_burst_length"),
        ("can_bus_off_every = -1.0\n", "[faults] can_bus_off_every"),
    ],
)
def test_bad_faults_are_refused_naming_the_key(table: str, named: str) -> None:
    with pytest.raises(BadInputError) as info:
        loads_scenario(MINIMAL + "[faults]\n" + table)
    assert named in str(info.value)


def test_cli_exits_2_on_a_bad_faults_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text(MINIMAL + "[faults]\nstate_drop_every = -2\n")
    assert main(["sim", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "[faults] state_drop_every" in capsys.readouterr().err


def test_run_settings_carry_the_faults_table(tmp_path: Path) -> None:
    scenario = tmp_path / "s.toml"
    scenario.write_text(MINIMAL + "[faults]\ncommand_drop_every = 5\n")
    _, settings, run_dir, _ = prepare(
        RunOptions(scenario=scenario, out=tmp_path / "run", duration=0.1)
    )
    expected = asdict(FaultsConfig(command_drop_every=5))
    assert settings.faults == expected
    assert RunSettings.load(run_dir / "run_settings.json").faults == expected
    resolved = tomllib.loads((run_dir / "scenario.resolved.toml").read_text())
    assert resolved["faults"] == expected
    assert RunSettings(scenario_path="x").faults == {}  # default: no injection


def test_impair_is_absent_unless_given_and_round_trips(tmp_path: Path) -> None:
    """No [impair]: none written back (a resolved file must not move a rerun into a network
    namespace); given: written with its defaults and read back the same."""
    plain = loads_scenario(MINIMAL)
    assert plain.impair is None and "impair" not in scenario_dict(plain)
    sc = loads_scenario(MINIMAL + '[impair]\non = "can"\nloss_every = 97\n', tmp_path)
    assert sc.impair == ImpairConfig(on="can", loss_every=97)
    controller, _, ctx = build_loop(sc)
    data = tomllib.loads(dumps_toml(resolved_dict(sc, controller, ctx)))
    assert data["impair"] == asdict(ImpairConfig(on="can", loss_every=97))
    assert parse_scenario(data, tmp_path).impair == sc.impair
    assert loads_scenario(MINIMAL + "[impair]\n").impair == ImpairConfig()  # count only


@pytest.mark.parametrize(
    ("table", "named"),
    [
        ("loss = 1.5\n", "[impair] loss must be in [0, 1]"),
        ("loss = -0.1\n", "[impair] loss must be >= 0"),
        ('loss = "1%"\n', "[impair] loss must be a number"),
        ("loss_every = 2.0\n", "[impair] loss_every must be an integer"),
        ("loss_every = -1\n", "[impair] loss_every must be >= 0"),
        ("loss = 0.1\nloss_every = 9\n", "[impair] loss = 0.1 and loss_every = 9 exclude"),
        ("rate_bps = 10\n", "[impair] rate_bps must be 0 (no limit) or at least 1000"),
        ("rate_bps = nan\n", "[impair] rate_bps must be finite"),
        ('on = "wifi"\n', "[impair] on must be one of 'all', 'can', 'zenoh'"),
        ('can_frames = "torque"\n', "[impair] can_frames = 'torque' selects CAN frames"),
        ('can_frames = "heartbeat"\non = "can"\n', "[impair] can_frames must be one of"),
        ("los = 0.1\n", "[impair]: unknown key(s) los"),
    ],
)
def test_bad_impair_is_refused_naming_the_key(table: str, named: str) -> None:
    with pytest.raises(BadInputError) as info:
        loads_scenario(MINIMAL + "[impair]\n" + table)
    assert str(info.value).startswith(named) and "\n" not in str(info.value)

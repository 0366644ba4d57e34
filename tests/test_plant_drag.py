"""The plant's optional losses: viscous friction and a top speed ([plant] friction, max_speed),
against closed forms, equal on floats and arrays, off in the paper's scenarios, and carried
from the scenario to the services' settings."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from controller_service.laws.base import Limits
from hil.bench.settings import scenario_settings
from hil.bundled import bundled_names, resolve_scenario
from hil.errors import BadInputError
from hil.scenario import load_scenario, loads_scenario, scenario_dict
from plant_emulator.disturbances import Disturbance
from plant_emulator.dynamics import NO_DRAG, Drag, Extremes, PlantState, rk4_array, rk4_float
from plant_emulator.from_settings import drag_of

LIMITS = Limits()
H = 1e-3


def _run(state: PlantState, cmd: tuple[float, float], seconds: float, drag: Drag, arrays: bool):
    n = round(seconds / H)
    ext = Extremes.zeros(2) if arrays else Extremes()
    if arrays:
        state = PlantState(*(np.full(2, float(f)) for f in state))
        cmds = (np.full(2, cmd[0]), np.full(2, cmd[1]))
        out = rk4_array(state, *cmds, 0.0, H, n, Disturbance(), 0.0, None, LIMITS, ext, 0, drag)
        return PlantState(*(float(np.asarray(f)[1]) for f in out)), ext
    out = rk4_float(state, *cmd, 0.0, H, n, Disturbance(), 0.0, None, LIMITS, ext, 0, drag)
    return out, ext


@pytest.mark.parametrize("arrays", [False, True], ids=["floats", "arrays"])
def test_friction_is_the_closed_form_exponential(arrays: bool) -> None:
    drag = Drag(c_v=0.8, c_omega=2.0)
    # coasting: v(t) = v0 exp(-c t)
    end, _ = _run(PlantState(0.0, 0.0, 0.0, 1.2, 0.5), (0.0, 0.0), 2.0, drag, arrays)
    assert end.v == pytest.approx(1.2 * math.exp(-0.8 * 2.0), rel=1e-10)
    assert end.omega == pytest.approx(0.5 * math.exp(-2.0 * 2.0), rel=1e-10)
    # a held torque from rest: v(t) = (tau/c) (1 - exp(-c t)), the position its integral
    end, _ = _run(PlantState(0.0, 0.0, 0.0, 0.0, 0.0), (0.4, 0.0), 3.0, drag, arrays)
    c, tau, t = 0.8, 0.4, 3.0
    assert end.v == pytest.approx(tau / c * (1 - math.exp(-c * t)), rel=1e-10)
    assert end.x == pytest.approx(tau / c * (t - (1 - math.exp(-c * t)) / c), rel=1e-9)


@pytest.mark.parametrize("arrays", [False, True], ids=["floats", "arrays"])
def test_top_speed_holds_at_every_step(arrays: bool) -> None:
    drag = Drag(v_max=0.5, omega_max=0.3)
    end, ext = _run(PlantState(0.0, 0.0, 0.0, 0.0, 0.0), (3.0, -2.0), 1.0, drag, arrays)
    assert (end.v, end.omega) == (0.5, -0.3)
    assert float(np.max(ext.max_abs_v)) == 0.5 and float(np.max(ext.max_abs_omega)) == 0.3
    assert float(np.max(ext.max_abs_tau1)) == 3.0  # the torque is not what is limited


def test_the_papers_scenarios_have_no_losses() -> None:
    for name in bundled_names():
        sc = load_scenario(resolve_scenario(name))
        assert sc.plant.drag == NO_DRAG and not sc.plant.drag.active, name
        assert drag_of(scenario_settings(sc)) is NO_DRAG


def test_losses_go_from_the_scenario_to_the_services_and_back() -> None:
    text = resolve_scenario("paper_tracking").read_text()
    sc = loads_scenario(text + "\n[plant]\nfriction = [0.5, 1.0]\nmax_speed = [1.5, 2.0]\n")
    assert sc.plant.drag == Drag(0.5, 1.0, 1.5, 2.0)
    assert drag_of(scenario_settings(sc)) == Drag(0.5, 1.0, 1.5, 2.0)
    # scenario.resolved.toml writes every default: an empty max_speed reads back as none
    plain = load_scenario(resolve_scenario("paper_tracking"))
    assert scenario_dict(plain)["plant"]["max_speed"] == []
    again = dataclasses.replace(plain.plant, max_speed=())
    assert again.drag == NO_DRAG


@pytest.mark.parametrize(
    ("table", "words"),
    [
        ("friction = [0.5]", "[plant] friction needs 2 values"),
        ("friction = [-0.1, 0.0]", "[plant] friction[0] must be in [0, 1e+06]"),
        ("max_speed = [0.0, 1.0]", "[plant] max_speed[0] must be > 0"),
        ("max_speed = [1.0, 2.0, 3.0]", "[plant] max_speed needs 2 values"),
        ("friction = 0.5", "[plant] friction must be a list"),
    ],
)
def test_bad_losses_are_refused_by_name(table: str, words: str) -> None:
    text = resolve_scenario("paper_tracking").read_text() + f"\n[plant]\n{table}\n"
    with pytest.raises(BadInputError) as info:
        loads_scenario(text)
    assert words in str(info.value)

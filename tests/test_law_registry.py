"""build_controller / resolved_controller_table: built-in laws, auto, user laws by import path."""

from __future__ import annotations

import math

import pytest

from controller_service.design import DesignError
from controller_service.laws.base import Controller, DesignContext, ReferenceSample, RobotState
from controller_service.registry import (
    BUILTIN_LAWS,
    build_controller,
    resolved_controller_table,
    resolved_notes,
)

CONTEXT = DesignContext()


def test_defaults_are_table1():
    controller = build_controller({}, CONTEXT)
    assert controller.name == "unified"
    assert resolved_controller_table(controller) == {
        "law": "unified",
        "m1": 0.5,
        "m2": 0.5,
        "l1": 0.5,
        "l2": 0.5,
        "lam": 1.0,
        "rho": 1.0,
    }
    boundary = build_controller({"law": "unified_boundary"}, CONTEXT)
    table = resolved_controller_table(boundary)
    assert boundary.name == "unified_boundary" and (table["eps1"], table["eps2"]) == (0.1, 0.1)


def test_auto_is_resolved_in_the_table_and_rebuilds_identically():
    controller = build_controller({"law": "unified", "lam": "auto", "rho": "auto"}, CONTEXT)
    table = resolved_controller_table(controller)
    assert 5.0 < table["lam"] < 5.96 and 0.0 < table["rho"] < 1.02
    assert len(resolved_notes(controller)) == 2
    again = build_controller(table, CONTEXT)
    assert resolved_controller_table(again) == table
    assert resolved_notes(again) == ()


def test_design_violation_surfaces_as_named_error():
    with pytest.raises(DesignError, match=r"\(11\)"):
        build_controller({"lam": 7.0}, CONTEXT)


@pytest.mark.parametrize(
    ("table", "words"),
    [
        ({"law": "unified", "lamda": 1.0}, "lamda"),
        ({"law": "unified", "eps1": 0.1}, "unified_boundary"),
        ({"law": "unified", "rho": "big"}, "rho must be a number"),
        ({"law": "unified", "m1": math.inf}, "m1 must be finite"),
        ({"law": "jiang1997", "c1": 7}, "[controller.jiang1997]"),
        ({"law": "jiang1997", "jiang1997": {"c3": 1}}, "c3"),
        ({"law": "jiang1997", "jiang1997": {"c1": -1}}, "c1 must be a finite number > 0"),
        ({"law": "jiang2001", "jiang2001": {"stab_eps": [1, 2]}}, "list of 3 numbers"),
        ({"law": "nonsense"}, "import path"),
        ({"law": "no_such_module_xyz:Thing"}, "cannot import"),
        ({"law": "tests.example_user_controller:Nope"}, "has no 'Nope'"),
        ({"law": "tests.example_user_controller:NotAController"}, "Controller protocol"),
        ({"law": "tests.example_user_controller:OldMemorySignature"}, "initial_memory must accept"),
        ({"law": "tests.example_user_controller:SaturatedPD", "bogus": 1}, "building it failed"),
        ({"law": 3}, "law must be a string"),
    ],
)
def test_bad_tables_are_refused_with_a_clear_value_error(table, words):
    with pytest.raises(ValueError) as info:
        build_controller(table, CONTEXT)
    assert words in str(info.value)


def test_baselines_build_with_their_subtables():
    j97 = build_controller({"law": "jiang1997", "jiang1997": {"c1": 7, "c2": 0.1}}, CONTEXT)
    assert j97.name == "jiang1997"
    assert resolved_controller_table(j97)["jiang1997"]["c1"] == 7.0
    j01 = build_controller({"law": "jiang2001", "jiang1997": {"c1": 1}}, CONTEXT)
    table = resolved_controller_table(j01)
    assert table["jiang2001"]["stab_eps"] == [1.6, 4.0, 1.0]
    assert table["jiang2001"]["track_lam"] == [4.5, 0.4, 1.1]
    assert isinstance(j97, Controller) and isinstance(j01, Controller)


def test_user_controller_loads_by_import_path_and_runs():
    table = {"law": "tests.example_user_controller:SaturatedPD", "gain": 100.0}
    controller = build_controller(table, CONTEXT)
    assert controller.name == "saturated_pd"
    memory = controller.initial_memory()
    out, memory = controller.update(
        0.0,
        1e-3,
        RobotState(0.0, 0.0, 0.0, 0.0, 0.0),
        ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2),
        memory,
    )
    assert (out.tau1, out.tau2) == (3.3, 20.0)
    assert resolved_controller_table(controller) == table


@pytest.mark.parametrize("law", BUILTIN_LAWS)
def test_every_law_takes_its_initial_adaptive_states_explicitly(law):
    # One call for every law (hil.sim and hil.bench pass [initial] z1, z2 without asking the law).
    table = {"law": law, **({"eps1": 0.1, "eps2": 0.1} if law == "unified_boundary" else {})}
    controller = build_controller(table, CONTEXT)
    one = controller.initial_memory(None, z1=0.2, z2=-0.1)
    many = controller.initial_memory(3, z1=0.2, z2=-0.1)
    if law.startswith("unified"):
        assert (one.z1, one.z2) == (0.2, -0.1)
        assert list(many.z1) == [0.2] * 3 and list(many.z2) == [-0.1] * 3
    else:  # no adaptive states of (8): z1, z2 change nothing
        assert one == controller.initial_memory(None)
        assert all(
            list(a) == list(b) for a, b in zip(many, controller.initial_memory(3), strict=True)
        )

"""Design constants and checks of Theorem 1: Table 1 passes, each broken condition is named."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest

from controller_service.design import (
    DesignError,
    check_unified,
    design_constants,
    lam_bound,
    resolve_auto,
    rho_bound,
)
from controller_service.laws.base import DesignContext, Limits
from controller_service.laws.unified import UnifiedController, UnifiedParams

PAPER = DesignContext()  # phi = (1.6, 5.1), varpi = (3.3, 51), mu = (0.5, 0.2), k = (1, 1)
TABLE1 = UnifiedParams()


def test_paper_constants_give_the_papers_bounds():
    c = design_constants(PAPER)
    assert c["c0"] == pytest.approx(2.1)
    assert c["c2"] == pytest.approx(3.39)
    lam_max = lam_bound(PAPER, m2=0.5, l2=0.5)
    rho_max = rho_bound(PAPER, m1=0.5, m2=0.5, l1=0.5, l2=0.5, lam=1.0)
    # docs/design.md: by (11)-(12) lam < 5.96, rho < 1.02 at Table 1.
    assert 5.95 < lam_max < 5.97
    assert 1.015 < rho_max < 1.025


def test_table1_passes():
    check_unified(TABLE1, PAPER)
    UnifiedController(TABLE1, PAPER)


def test_disturbance_bound_s1_enters_c5():
    base = design_constants(PAPER)["c5"]
    with_s1 = design_constants(dataclasses.replace(PAPER, s1=0.2))["c5"]
    assert with_s1 == pytest.approx(base + 0.2)


BROKEN = [
    (dict(m1=1.2), "(9) m1 < phi1 - mu1", 1.2, 1.1),
    (dict(m2=5.0), "(9) m2 < phi2 - mu2", 5.0, 4.9),
    (dict(l1=2.5), "(9) l1 < varpi1 - k1 - s1", 2.5, 2.3),
    (dict(l2=50.5), "(9) l2 < varpi2 - k2 - s2", 50.5, 50.0),
    (dict(lam=6.0), "(11)", 6.0, None),
    (dict(rho=1.05), "(12)", 1.05, None),
]


@pytest.mark.parametrize(("change", "condition", "value", "bound"), BROKEN)
def test_each_broken_condition_is_refused_by_name(change, condition, value, bound):
    params = dataclasses.replace(TABLE1, **change)
    with pytest.raises(DesignError) as info:
        UnifiedController(params, PAPER)
    err = info.value
    assert isinstance(err, ValueError)
    assert err.condition.startswith(condition)
    assert err.value == pytest.approx(value)
    if bound is not None:
        assert err.bound == pytest.approx(bound)
    assert err.condition in str(err)
    assert f"{err.value:.6g}" in str(err) and f"{err.bound:.6g}" in str(err)


@pytest.mark.parametrize(
    ("context", "condition"),
    [
        (dataclasses.replace(PAPER, mu1=1.7), "Assumption 2 mu1 < phi1"),
        (dataclasses.replace(PAPER, mu2=5.2), "Assumption 2 mu2 < phi2"),
        (dataclasses.replace(PAPER, k1=3.0, s1=0.5), "Assumption 2 k1 < varpi1 - s1"),
        (dataclasses.replace(PAPER, k2=60.0), "Assumption 2 k2 < varpi2 - s2"),
    ],
)
def test_assumption2_is_checked(context, condition):
    with pytest.raises(DesignError) as info:
        check_unified(TABLE1, context)
    assert info.value.condition == condition


def test_rho_just_below_bound_passes_and_nan_is_refused():
    rho_max = rho_bound(PAPER, m1=0.5, m2=0.5, l1=0.5, l2=0.5, lam=1.0)
    check_unified(dataclasses.replace(TABLE1, rho=0.999 * rho_max), PAPER)
    with pytest.raises(DesignError):
        check_unified(dataclasses.replace(TABLE1, rho=rho_max), PAPER)
    with pytest.raises(DesignError):
        check_unified(dataclasses.replace(TABLE1, lam=math.nan), PAPER)
    with pytest.raises(DesignError) as info:
        check_unified(dataclasses.replace(TABLE1, rho=0.0), PAPER)
    assert info.value.condition == "rho > 0"


def test_auto_gives_admissible_values_below_the_papers_bounds():
    params = {"m1": 0.5, "m2": 0.5, "l1": 0.5, "l2": 0.5, "lam": "auto", "rho": "auto"}
    resolved = resolve_auto(params, PAPER)
    lam, rho = resolved.params["lam"], resolved.params["rho"]
    assert 5.0 < lam < 5.96
    # rho is bounded with the resolved lam, which is smaller than at lam = 1.
    assert 0.0 < rho < 1.02
    assert rho == pytest.approx(0.9 * rho_bound(PAPER, m1=0.5, m2=0.5, l1=0.5, l2=0.5, lam=lam))
    check_unified(UnifiedParams(**resolved.params), PAPER)
    assert len(resolved.notes) == 2 and "(11)" in resolved.notes[0]


def test_auto_with_fixed_lam_one_gives_rho_below_1_02():
    params = {"m1": 0.5, "m2": 0.5, "l1": 0.5, "l2": 0.5, "lam": 1.0, "rho": "auto"}
    rho = resolve_auto(params, PAPER).params["rho"]
    assert 0.9 < rho < 1.02


def test_pure_stabilization_lam_bound_is_infinite_and_auto_is_finite():
    context = DesignContext(Limits(), mu1=0.0, mu2=0.0, k1=0.0, k2=0.0)
    assert math.isinf(lam_bound(context, m2=0.5, l2=0.5))
    resolved = resolve_auto(
        {"m1": 0.5, "m2": 0.5, "l1": 0.5, "l2": 0.5, "lam": "auto", "rho": "auto"}, context
    )
    assert resolved.params["lam"] == 1.0
    assert math.isfinite(resolved.params["rho"])
    assert any("no finite bound" in note for note in resolved.notes)
    check_unified(UnifiedParams(**resolved.params), context)


def test_auto_refuses_a_design_breaking_9_before_computing_a_bound():
    with pytest.raises(DesignError) as info:
        resolve_auto({"m1": 0.5, "m2": 6.0, "l1": 0.5, "l2": 0.5, "lam": "auto", "rho": 1}, PAPER)
    assert info.value.condition == "(9) m2 < phi2 - mu2"


def test_free_form_records_are_as_few_as_docs_architecture_says() -> None:
    """Facts cross modules as typed records; ``dict[str, Any]`` stays only where
    docs/architecture.md ("Free-form records") says why, in as many places as it says (at most
    60), and its reasons add up to that number."""
    import re

    root = Path(__file__).resolve().parent.parent
    places = sum(
        line.count("dict[str, Any]") > 0
        for path in (root / "hil").rglob("*.py")
        for line in path.read_text().splitlines()
    )
    doc = (root / "docs" / "architecture.md").read_text()
    said = re.search(r"`dict\[str, Any\]`\s+remains\s+in (\d+) places", doc)
    assert said is not None, "docs/architecture.md no longer counts the free-form records"
    reasons = [int(n) for n in re.findall(r"^- \*\*[^*]+\*\* \((\d+)\)", doc, re.M)]
    assert places == int(said.group(1)) == sum(reasons), (places, said.group(1), reasons)
    assert places <= 60

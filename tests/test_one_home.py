"""One home for each shared constant: the paper's limits and Table 1
(protocol.paper), schema versions (protocol.versions), angle wrapping (protocol.angles)."""

from __future__ import annotations

import ast
import tomllib
from pathlib import Path

from controller_service.laws.base import Limits
from controller_service.laws.unified import UnifiedParams
from hil.bench.defaults import PAPER_TRACKING_TOML
from hil.bundled import bundled_path
from protocol.paper import PAPER_LIMITS, TABLE1

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("protocol", "controller_service", "plant_emulator", "hil")


def _product_modules():
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            yield path.relative_to(REPO).as_posix(), ast.parse(path.read_text(encoding="utf-8"))


def test_the_defaults_are_the_paper_s():
    assert Limits() == Limits(**PAPER_LIMITS)
    params = UnifiedParams()
    assert {k: getattr(params, k) for k in TABLE1} == dict(TABLE1)
    # hil run's default scenario is the bundled paper_tracking with the run's defaults over it:
    # the same initial condition, gains and reference (one name, one scenario).
    default = tomllib.loads(PAPER_TRACKING_TOML)
    bundled = tomllib.loads(bundled_path("paper_tracking").read_text())
    for table in ("reference", "initial", "controller"):
        assert default[table] == bundled[table], table
    assert default.get("limits", PAPER_LIMITS) == dict(PAPER_LIMITS)
    assert {k: default["controller"][k] for k in TABLE1} == dict(TABLE1)


def test_schema_versions_and_angle_wrapping_are_defined_once():
    homes = {"SCHEMA_VERSION": "protocol/versions.py", "wrap_angle": "protocol/angles.py"}
    found: dict[str, list[str]] = {name: [] for name in homes}
    for rel, tree in _product_modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and node.name in found:
                found[node.name].append(rel)
            if isinstance(node, ast.Assign):
                for target in node.targets:
                    if isinstance(target, ast.Name) and target.id.endswith("SCHEMA_VERSION"):
                        found["SCHEMA_VERSION"].append(rel)
    assert set(found["SCHEMA_VERSION"]) == {homes["SCHEMA_VERSION"]}
    assert found["wrap_angle"] == [homes["wrap_angle"]]

"""Imports only point down (docs/architecture.md): import-linter's contracts of pyproject.toml
hold, the bench wing and the analysis wing of hil never import each other, and no two modules
of the product import each other, directly or around a loop."""

from __future__ import annotations

import shutil
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("hil", "controller_service", "plant_emulator", "runtime", "protocol")


def import_cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative): each is
    a set of modules that import one another around a loop."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph.modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append(
                        (child, iter(sorted(graph.find_modules_directly_imported_by(child))))
                    )
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    component.append(m)
                    if m == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def _lint_imports() -> str:
    found = shutil.which("lint-imports") or str(Path(sys.executable).parent / "lint-imports")
    if not Path(found).exists():
        pytest.fail("lint-imports is not installed (the test extra of pyproject.toml has it)")
    return found


def test_import_contracts_hold() -> None:
    proc = subprocess.run(
        [_lint_imports(), "--no-cache"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "broken" in proc.stdout and " 0 broken" in proc.stdout, proc.stdout


def test_the_bench_and_the_analysis_never_import_each_other() -> None:
    """The two wings of hil (docs/architecture.md, "Inside hil") are kept apart by a contract of
    their own, and no chain of imports joins them in either direction."""
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    wings = {"hil.bench", "hil.analysis"}
    assert any(
        c["type"] == "independence" and set(c["modules"]) == wings for c in contracts["contracts"]
    )
    graph = grimp.build_graph("hil", cache_dir=None)
    for importer, imported in (("hil.bench", "hil.analysis"), ("hil.analysis", "hil.bench")):
        chain = graph.find_shortest_chain(importer, imported, as_packages=True)
        assert chain is None, f"{importer} reaches {imported}: {' -> '.join(chain or ())}"


def test_no_module_imports_itself_around_a_loop() -> None:
    graph = grimp.build_graph(*PACKAGES, cache_dir=None)
    assert "controller_service.service" in graph.modules  # the graph is the product's
    assert import_cycles(graph) == []


def test_the_cycle_check_finds_a_loop(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pkg = tmp_path / "loopy"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from loopy import b\n")
    (pkg / "b.py").write_text("def f():\n    from loopy import c\n")  # a lazy import counts
    (pkg / "c.py").write_text(textwrap.dedent("import loopy.a\n"))
    (pkg / "d.py").write_text("import loopy.a\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    graph = grimp.build_graph("loopy", cache_dir=None)
    assert import_cycles(graph) == [["loopy.a", "loopy.b", "loopy.c"]]

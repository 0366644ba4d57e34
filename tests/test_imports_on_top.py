"""Imports sit at the top of every module of hil, except in the command line: ``hil.cli`` and
``hil.commands`` import their job when it runs, which is what keeps ``hil --help`` from loading
numpy, Zenoh, matplotlib and the CAN stack (the second test shows why that is needed)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: Where an import inside a function is allowed, and why: the CLI's start-up time.
LAZY = ("hil/cli.py", "hil/commands/")
HEAVY = ("numpy", "matplotlib", "zenoh", "can", "mcap", "cantools")


def function_level_imports(path: Path) -> list[int]:
    tree = ast.parse(path.read_text())
    lines = []
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            lines += [n.lineno for n in ast.walk(fn) if isinstance(n, ast.Import | ast.ImportFrom)]
    return sorted(set(lines))


def test_no_import_inside_a_function_outside_the_command_line() -> None:
    found = []
    for path in sorted((ROOT / "hil").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(LAZY):
            continue
        found += [f"{rel}:{line}" for line in function_level_imports(path)]
    assert not found, "imports inside functions (move them to the top):\n" + "\n".join(found)


def test_the_command_line_starts_without_the_heavy_libraries() -> None:
    code = f"import sys, hil.cli; print([m for m in {HEAVY!r} if m in sys.modules])"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert out.stdout.strip() == "[]", out.stdout


def test_the_check_sees_an_import_inside_a_function(tmp_path: Path) -> None:
    f = tmp_path / "m.py"
    f.write_text("import os\n\n\ndef g():\n    import json\n    return json\n")
    assert function_level_imports(f) == [5]

"""Code shape of the product packages: no function longer than MAX_LINES.

A long function does several jobs; split it into named pieces that say them. The count is
``end_lineno - lineno + 1`` of every ``def``, read with :mod:`ast`: from the def line (so
decorators are not counted, the docstring is); a nested function counts on its own and inside
its parent.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("protocol", "runtime", "controller_service", "plant_emulator", "hil")
MAX_LINES = 80


def function_lengths(root: Path = REPO) -> dict[str, int]:
    """``path::name`` -> lines of every function of the product packages (the longest when a
    module defines one name twice)."""
    out: dict[str, int] = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    key = f"{rel}::{node.name}"
                    length = node.end_lineno - node.lineno + 1
                    out[key] = max(out.get(key, 0), length)
    return out


def long_functions(lengths: dict[str, int]) -> dict[str, int]:
    return {key: n for key, n in lengths.items() if n > MAX_LINES}


def test_no_product_function_is_longer_than_the_limit():
    # No exception: a function that must be longer is split into named pieces instead.
    too_long = long_functions(function_lengths())
    assert not too_long, (
        f"functions over {MAX_LINES} lines (split them into named pieces): "
        + ", ".join(f"{k} ({n})" for k, n in sorted(too_long.items()))
    )


@pytest.mark.parametrize("extra", [MAX_LINES - 1, MAX_LINES])
def test_the_count_fails_a_long_function_and_passes_one_at_the_limit(tmp_path, extra):
    # A def line plus ``extra`` body lines: MAX_LINES - 1 extra lines is exactly the limit.
    pkg = tmp_path / "hil"
    pkg.mkdir()
    body = "".join(f"    x{i} = {i}\n" for i in range(extra))
    (pkg / "mod.py").write_text(f"def f():\n{body}")
    for name in PACKAGES[:-1]:
        (tmp_path / name).mkdir()
    lengths = function_lengths(tmp_path)
    assert lengths == {"hil/mod.py::f": extra + 1}
    assert bool(long_functions(lengths)) == (extra + 1 > MAX_LINES)

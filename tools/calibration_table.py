"""docs/realtime.md's calibration table, written from the tests that calibrate each figure.

Each known-answer test declares what it calibrates with ``@calibrates(FIGURE, ...,
injects=..., found=...)`` (tests/calibrates.py): the synthetic ones in
tests/test_known_answers.py (scripted hop logs, exact answers), the real-process ones in
tests/test_calibration.py. This reads those declarations from the source (no test is imported
or run) and renders one table row per figure and test, in the order of the "Timing figures"
table; tests/test_known_answers.py fails when the document's table is not this one, so the
document cannot claim a calibration no test declares.

    python -m tools.calibration_table           # print the table; exit 1 if the doc differs
    python -m tools.calibration_table --write   # rewrite the table in docs/realtime.md
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "realtime.md"
SOURCES = {
    "synthetic logs": (ROOT / "tests" / "test_known_answers.py",),
    "real processes": (
        ROOT / "tests" / "test_calibration.py",
        ROOT / "tests" / "test_rate_below_sensor.py",
    ),
}
BEGIN = "<!-- calibration table: written by `python -m tools.calibration_table --write` -->"
END = "<!-- end of the calibration table -->"
PATH_VARIANTS = ("zenoh (applied)", "can (applied)", "can (shadow)")  # of a `..._<path>` figure


@dataclass(frozen=True)
class Declaration:
    """One ``@calibrates`` of one test."""

    kind: str  # a key of SOURCES
    module: str  # file name
    test: str
    figures: tuple[str, ...]
    injects: str
    found: str
    source: str  # the test function's source text


def _text(node: ast.expr) -> str:
    if not (isinstance(node, ast.Constant) and isinstance(node.value, str)):
        raise ValueError(f"line {node.lineno}: @calibrates takes string literals only")
    return node.value


def declarations(sources: dict[str, tuple[Path, ...]] = SOURCES) -> list[Declaration]:
    """Every ``@calibrates`` on a test function, in source order (decorators top down)."""
    out = []
    for kind, path in ((k, p) for k, paths in sources.items() for p in paths):
        text = path.read_text()
        for node in ast.parse(text).body:
            if not isinstance(node, ast.FunctionDef):
                continue
            for dec in node.decorator_list:
                if not (isinstance(dec, ast.Call) and getattr(dec.func, "id", "") == "calibrates"):
                    continue
                if not node.name.startswith("test_"):
                    raise ValueError(f"{path.name}:{node.lineno}: @calibrates on a non-test")
                kw = {k.arg: _text(k.value) for k in dec.keywords}
                out.append(
                    Declaration(
                        kind, path.name, node.name, tuple(_text(a) for a in dec.args),
                        kw["injects"], kw["found"], ast.get_source_segment(text, node) or "",
                    )
                )  # fmt: skip
    return out


def section(text: str, heading: str) -> str:
    """The body of the markdown section whose heading line starts with ``heading``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(heading))
    level = len(heading) - len(heading.lstrip("#"))
    body = []
    for line in lines[start + 1 :]:
        m = re.match(r"(#+) ", line)
        if m and len(m.group(1)) <= level:
            break
        body.append(line)
    return "\n".join(body)


def doc_figures(text: str) -> list[str]:
    """The figures of the "Timing figures" table, in order: the names in each row's first
    column (a bare ``_rate`` is the preceding name's rate), a ``..._<path>`` figure once per
    path and role (PATH_VARIANTS)."""
    names: list[str] = []
    for line in section(text, "## Timing figures").splitlines():
        if not line.startswith("| `"):
            continue
        prev = ""
        for name in re.findall(r"`([^`]+)`", line.split("|")[1]):
            name = prev + name if name.startswith("_") else name
            prev = name
            if name.endswith("<path>"):
                names += [name.replace("<path>", v) for v in PATH_VARIANTS]
            elif name not in names:
                names.append(name)
    return names


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def render(decls: list[Declaration], figures: list[str]) -> str:
    """The table: one row per (figure, test), figures in the document's order, the synthetic
    answers before the real ones."""
    rows = [
        "| figure | known answer | injected | found within | test |",
        "|---|---|---|---|---|",
    ]
    kinds = list(SOURCES)
    for fig in figures:
        for d in sorted((d for d in decls if fig in d.figures), key=lambda d: kinds.index(d.kind)):
            rows.append(
                f"| `{fig}` | {d.kind} | {_cell(d.injects)} | {_cell(d.found)} | "
                f"{d.module}::{d.test} |"
            )
    return "\n".join(rows)


def generated(text: str) -> str:
    """The document's table between BEGIN and END."""
    return text.split(BEGIN, 1)[1].split(END, 1)[0].strip("\n")


def write(text: str, table: str) -> str:
    head, rest = text.split(BEGIN, 1)
    return f"{head}{BEGIN}\n{table}\n{END}{rest.split(END, 1)[1]}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="rewrite docs/realtime.md's table")
    args = ap.parse_args(argv)
    text = DOC.read_text()
    table = render(declarations(), doc_figures(text))
    if args.write:
        DOC.write_text(write(text, table))
        return 0
    print(table)
    return 0 if generated(text) == table else 1


if __name__ == "__main__":
    sys.exit(main())

"""Everything the README, the docs and the code cite is in the repository: relative links and
repository paths resolve, every ``NAME.md`` named exists, nothing points outside the repository
(``../``), and no ticket number leaks into docs, code or output strings."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOP = ("docs", "hil", "controller_service", "plant_emulator", "protocol", "runtime", "tests",
       "bench", "deploy", "tools", ".ci")  # fmt: skip
# A file in the repository: a top folder, name characters, an extension (a trailing dot or
# comma is the sentence's). Without an extension it may be a Zenoh key (hil/robot0/state).
PATH = re.compile(
    r"(?<![\w./-])(?:" + "|".join(re.escape(t) for t in TOP) + r")/[\w./-]*\.[A-Za-z0-9]+\b(?!/)"
)
LINK = re.compile(r"\]\(([^)\s]+)\)")
MD_NAME = re.compile(r"(?<![\w/.-])([\w-]+\.md)\b")
# Files the bench writes into a run, sweep, comparison or paper folder: named, not shipped.
WRITTEN = {"report.md", "compare.md", "sweep.md", "table.md"}


def _tracked(*patterns: str) -> list[Path]:
    out = subprocess.run(
        ["git", "ls-files", *patterns], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    return [ROOT / p for p in out]


def _docs() -> list[Path]:
    return [ROOT / "README.md", *_tracked("docs/*.md")]


def _code() -> list[Path]:
    return [p for p in _tracked("*.py") if not p.name.startswith("test_docs_references")]


def _exists(cited: str) -> bool:
    path = cited.rstrip(".")
    if any(c in path for c in "*{}<>"):
        return True  # a pattern or a placeholder, not one file
    return (ROOT / path).exists()


@pytest.mark.parametrize("doc", _docs(), ids=lambda p: p.name)
def test_relative_links_and_cited_paths_of_the_docs_resolve(doc: Path) -> None:
    text = doc.read_text()
    missing = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue  # a URL or an anchor
        if not (doc.parent / target.split("#")[0]).exists():
            missing.append(target)
    missing += [p for p in PATH.findall(text) if not _exists(p)]
    assert not missing, f"{doc.name} cites what the repository does not hold: {missing}"


def test_every_markdown_file_named_anywhere_exists() -> None:
    names = {p.name for p in _tracked("*.md")}
    missing = {}
    for f in [*_docs(), *_code()]:
        for name in MD_NAME.findall(f.read_text()):
            if name not in names and name not in WRITTEN:
                missing.setdefault(name, []).append(str(f.relative_to(ROOT)))
    assert not missing, f"named but not in the repository: {missing}"


def test_paths_cited_by_the_code_resolve() -> None:
    missing = {}
    for f in _code():
        for p in PATH.findall(f.read_text()):
            if p.startswith("docs/") and not _exists(p):
                missing.setdefault(p, []).append(str(f.relative_to(ROOT)))
    assert not missing, f"docs cited by the code but missing: {missing}"


def test_nothing_points_outside_the_repository() -> None:
    outside = re.compile(r"\.\./shared|\bDESIGN\.md|\bCONTRACT\.md")
    hits = [
        str(f.relative_to(ROOT))
        for f in [*_docs(), *_code(), *_tracked("*.toml")]
        if outside.search(f.read_text())
    ]
    assert not hits, hits


def test_no_ticket_numbers_in_docs_code_or_output() -> None:
    ticket = re.compile(r"\b(?:issue|ticket)s? #?\d+", re.IGNORECASE)
    hits = [
        f"{f.relative_to(ROOT)}: {m.group(0)}"
        for f in [*_docs(), *_code(), *_tracked("*.toml")]
        for m in ticket.finditer(f.read_text())
    ]
    assert not hits, hits


def test_robot_id_is_an_integer_in_scenarios_and_robot_n_on_the_wire() -> None:
    """docs/scenario.md and docs/protocol.md tell one story, the code's."""
    from hil.errors import BadInputError
    from hil.run.settings import robot_id_of
    from hil.scenario import loads_scenario

    base = '[reference]\nkind = "circle"\n[initial]\n[zenoh]\n'
    assert robot_id_of(loads_scenario(base + "robot_id = 3\n")) == "robot3"
    with pytest.raises(BadInputError, match="robot_id must be an integer"):
        loads_scenario(base + 'robot_id = "robot3"\n')
    scenario_doc = (ROOT / "docs" / "scenario.md").read_text()
    protocol_doc = (ROOT / "docs" / "protocol.md").read_text()
    assert "an integer" in scenario_doc and "`robot<N>`" in scenario_doc
    assert "integer N" in protocol_doc and "`robot<N>`" in protocol_doc

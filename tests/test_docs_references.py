"""Everything the README, the docs and the code cite is in the repository: relative links and
repository paths resolve, every ``NAME.md`` named exists, nothing points outside the repository
(``../``), no ticket number leaks into docs, code or output strings, and what the docs' code
imports is installed by the README's first command or by the doc itself."""

from __future__ import annotations

import importlib.metadata
import re
import subprocess
import sys
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
WRITTEN = {"report.md", "compare.md", "sweep.md", "table.md", "campaign.md"}


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
        path = (doc.parent / target.split("#")[0]).resolve()
        if not path.is_relative_to(ROOT) or not path.exists():  # a sibling checkout is not ours
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
    # "issue 2", "ticket #7", and a pointer to one without its number ("the target")
    ticket = re.compile(
        r"\b(?:issue|ticket)s? #?\d+|\b(?:the|this) (?:issue|ticket)\b|\b(?:issue|ticket)'s\b",
        re.IGNORECASE,
    )
    hits = [
        f"{f.relative_to(ROOT)}: {m.group(0)}"
        for f in [*_docs(), *_code(), *_tracked("*.toml")]
        for m in ticket.finditer(f.read_text())
    ]
    assert not hits, hits


def test_robot_id_is_an_integer_in_scenarios_and_robot_n_on_the_wire() -> None:
    """docs/scenario.md and docs/protocol.md tell one story, the code's."""
    from hil.bench.settings import robot_id_of
    from hil.errors import BadInputError
    from hil.scenario import loads_scenario

    base = '[reference]\nkind = "circle"\n[initial]\n[zenoh]\n'
    assert robot_id_of(loads_scenario(base + "robot_id = 3\n")) == "robot3"
    with pytest.raises(BadInputError, match="robot_id must be an integer"):
        loads_scenario(base + 'robot_id = "robot3"\n')
    scenario_doc = (ROOT / "docs" / "scenario.md").read_text()
    protocol_doc = (ROOT / "docs" / "protocol.md").read_text()
    assert "an integer" in scenario_doc and "`robot<N>`" in scenario_doc
    assert "integer N" in protocol_doc and "`robot<N>`" in protocol_doc


# A line of a code block (fenced, or indented four spaces) that imports: its module names.
IMPORT = re.compile(r"^(?:\s{4,}|)(?:from\s+([\w.]+)\s+import\b|import\s+([\w., ]+))")
PIP = re.compile(r"pip install\s+([^#\n]+)")


def _dist_name(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _code_imports(text: str) -> set[str]:
    """Top-level modules imported by the doc's code blocks (not by its prose)."""
    out, fenced = set(), False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if not (fenced or line.startswith("    ")):
            continue
        m = IMPORT.match(line.strip() if fenced else line)
        if m:
            names = m.group(1) or m.group(2)
            out |= {n.strip().split(".")[0] for n in names.split(",") if n.strip()}
    return out


def _pip_installs(text: str) -> set[str]:
    """Distributions a doc tells the reader to install (pip install NAME==V, 'NAME[x]')."""
    out = set()
    for args in PIP.findall(text):
        for word in args.split():
            word = word.strip("'\"`")
            if word and not word.startswith("-") and word not in (".", "-r"):
                out.add(_dist_name(re.split(r"[\[=<>~!;]", word)[0]))
    return out


def test_what_the_docs_import_is_installed_by_the_first_command_or_by_the_doc() -> None:
    """A reader who ran the README's first command (requirements.lock) can run every code
    block of the docs, or the doc says what to install first."""
    locked = {
        _dist_name(line.split("==")[0])
        for line in (ROOT / "requirements.lock").read_text().splitlines()
        if "==" in line and not line.startswith((" ", "#"))
    }
    ours = {*TOP, "hil", "hil_smc_bench"}
    owners = importlib.metadata.packages_distributions()
    missing, checked = [], set()
    for doc in _docs():
        text = doc.read_text()
        given = locked | _pip_installs(text)
        for module in sorted(_code_imports(text)):
            if module in sys.stdlib_module_names or module in ours:
                continue
            dists = {_dist_name(d) for d in owners.get(module, [])}
            checked |= dists
            if not dists & given:
                missing.append(f"{doc.name}: {module} ({', '.join(sorted(dists)) or '?'})")
    assert not missing, f"imported by the docs, installed by nothing they say: {missing}"
    assert {"odrive-can", "python-can"} <= checked  # docs/can.md's client example was read

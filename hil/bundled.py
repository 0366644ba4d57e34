"""The scenarios that ship inside the package (``hil/scenarios/*.toml``) and the one function
that turns a command's SCENARIO argument (a path, or a bundled name with or without ``.toml``:
``hil sim paper_tracking``) into a file: :func:`resolve_scenario`.

The files are found with :mod:`importlib.resources`, so they are there after a non-editable
``pip install`` from any working directory. A scenario's relative paths (a ``csv`` reference,
a replay file) are relative to the scenario file: bundled scenarios are therefore always read
from one real folder holding all of them (the package's own, or, for a package imported from
a zip, a copy made once per process and removed at exit).
"""

from __future__ import annotations

import atexit
import functools
import itertools
import shutil
import tempfile
from importlib import resources
from pathlib import Path

from hil.errors import BadInputError

SUFFIX = ".toml"


@functools.cache
def bundled_dir() -> Path:
    """The real folder holding the bundled scenarios and the files they refer to."""
    root = resources.files("hil").joinpath("scenarios")
    if isinstance(root, Path):
        return root
    copy = Path(tempfile.mkdtemp(prefix="hil-scenarios-"))
    atexit.register(shutil.rmtree, copy, True)
    for entry in root.iterdir():
        if entry.is_file():
            (copy / entry.name).write_bytes(entry.read_bytes())
    return copy


def bundled_names() -> list[str]:
    """Names of the bundled scenarios (file names without ``.toml``), sorted."""
    return sorted(p.stem for p in bundled_dir().glob(f"*{SUFFIX}") if p.is_file())


def bundled_path(name: str) -> Path:
    """The file of the bundled scenario ``name`` (``.toml`` optional); BadInputError if none."""
    stem = name[: -len(SUFFIX)] if name.endswith(SUFFIX) else name
    if stem in bundled_names():
        return bundled_dir() / f"{stem}{SUFFIX}"
    raise BadInputError(_unknown(name))


def resolve_scenario(arg: str | Path) -> Path:
    """A command's SCENARIO argument as a file: an existing path as given, else the bundled
    scenario of that name. BadInputError (exit 2) names the bundled scenarios otherwise."""
    path = Path(arg)
    if path.exists():
        return path
    text = str(arg)
    if path.name != text:  # a folder part: a path, and it does not exist
        raise BadInputError(_unknown(text))
    return bundled_path(text)


def _unknown(text: str) -> str:
    names = ", ".join(bundled_names()) or "none"
    return (
        f"scenario {text!r}: no such file and no bundled scenario of that name "
        f"(bundled: {names}; `hil scenarios` describes them)"
    )


def description(path: Path) -> str:
    """One line about a scenario: the first sentence of the comment that opens the file."""
    lines = (line.strip() for line in path.read_text(encoding="utf-8").splitlines())
    comment = itertools.takewhile(lambda line: line.startswith("#"), lines)
    text = " ".join(part for part in (line.lstrip("#").strip() for line in comment) if part)
    end = text.find(". ")
    return text if end < 0 else text[: end + 1]

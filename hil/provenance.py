"""Provenance of a run (package version, git commit, host, start time) and a small TOML writer."""

from __future__ import annotations

import datetime as _dt
import functools
import platform
import re
import subprocess
from collections.abc import Mapping
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _dist_version
from pathlib import Path
from typing import Any

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def package_version() -> str:
    try:
        return _dist_version("hil-smc-bench")
    except PackageNotFoundError:
        return "0+unknown"


@functools.cache
def git_commit(start: Path | None = None) -> str:
    """The commit of the source tree (with ``-dirty`` when it has changes), or "" outside git.

    Asked once per process: the code running does not change under it, and a sweep resolves
    its scenario for every batch."""
    cwd = start or Path(__file__).resolve().parent
    git = functools.partial(subprocess.run, cwd=cwd, capture_output=True, text=True, timeout=5)
    try:
        head = git(["git", "rev-parse", "HEAD"])
        if head.returncode != 0:
            return ""
        dirty = git(["git", "status", "--porcelain", "--untracked-files=no"])
        return head.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return ""


#: A TOML document or table as tomllib reads it and :func:`dumps_toml` writes it: a scenario's
#: tables before hil.scenario.parse_scenario checks them, scenario.resolved.toml, a [controller]
#: table (a user's law takes the parameters it declares). Free-form by nature: the typed form is
#: hil.scenario.Scenario (docs/architecture.md, "Free-form records").
Toml = dict[str, Any]


def provenance(seeds: Mapping[str, Any], start_time: _dt.datetime | None = None) -> Toml:
    """The [provenance] table of scenario.resolved.toml."""
    start = start_time or _dt.datetime.now(_dt.UTC)
    return {
        "package_version": package_version(),
        "git_commit": git_commit(),
        "host": platform.node(),
        "python": platform.python_version(),
        "start_time": start.isoformat(timespec="seconds"),
        "seeds": dict(seeds),
    }


# A TOML basic string escapes backslash, quote and every control character (a string read from
# TOML may hold any of them as an escape, and must be written back as one).
_ESCAPES = str.maketrans({"\\": "\\\\", '"': '\\"', "\n": "\\n", "\t": "\\t", "\r": "\\r"})
_ESCAPES.update({c: f"\\u{c:04x}" for c in [*range(32), 127] if c not in _ESCAPES})


def _string(text: str) -> str:
    return '"' + text.translate(_ESCAPES) + '"'


def _key(k: str) -> str:
    return k if _BARE_KEY.match(k) else _string(k)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):  # repr writes nan, inf and -inf as TOML does
        return repr(v)
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, Path):
        return _value(str(v))
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_toml(data: Mapping[str, Any]) -> str:
    """TOML text of nested tables of scalars, lists and tables (None values are left out)."""
    lines: list[str] = []

    def table(prefix: str, body: Mapping[str, Any]) -> None:
        scalars = [(k, v) for k, v in body.items() if v is not None and not isinstance(v, Mapping)]
        subs = [(k, v) for k, v in body.items() if isinstance(v, Mapping)]
        body = [f"{_key(k)} = {_value(v)}" for k, v in scalars]
        if prefix and (scalars or not subs):
            body = [f"[{prefix}]", *body, ""]
        lines.extend(body)
        for k, v in subs:
            table(f"{prefix}.{_key(k)}" if prefix else _key(k), v)

    table("", data)
    return "\n".join(lines).rstrip() + "\n"

"""The one rule for the folder a command writes (``--out``): new, or replaced whole.

A folder that already holds files (a run, any command's output) is refused with one line
(exit 2) before anything runs, so no command ever leaves a stale file (an old report, an old
plot) beside new ones; ``--force`` replaces it whole instead. ``--force`` only ever deletes a
folder a hil command wrote (it holds :data:`MARKER`, or a run's own files), never one of the
user's. :func:`check` is called with the other input checks, :func:`take` right before the
command's first write.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

from hil.errors import BadInputError
from hil.folder import layout
from hil.options import out_dir
from hil.provenance import dumps_toml
from hil.scenario import build_loop, resolved_dict

#: Written into every folder a command takes: what wrote it, so that ``--force`` may replace it.
MARKER = ".hil-output"
#: Files by which a folder written before the marker existed is known as hil's own.
_KNOWN = (MARKER, layout.SUMMARY, layout.SCENARIO_RESOLVED, layout.RUN_SETTINGS, layout.FLEET_JSON)
_SHOWN = 3  # file names a refusal lists


def check(where: str, path: Path | None, force: bool, default: str | None = None) -> None:
    """BadInputError when ``path`` cannot be written (:func:`hil.options.out_dir`), holds
    files and ``force`` is off, or holds files no hil command wrote (``force`` on)."""
    out_dir(where, path, default)
    if path is None or not path.is_dir():
        return
    names = sorted(p.name for p in path.iterdir())
    if not names:
        return
    more = len(names) - _SHOWN
    shown = ", ".join(names[:_SHOWN]) + (f" and {more} more" if more > 0 else "")
    if not force:
        raise BadInputError(
            f"{where} {path}: already holds files ({shown}); give a new folder, or add --force "
            "to replace it whole"
        )
    if not any((path / name).exists() for name in _KNOWN):
        raise BadInputError(
            f"{where} {path}: holds files that no hil command wrote ({shown}); --force replaces "
            "only a folder hil wrote"
        )


def take(path: Path, command: str) -> Path:
    """Empty ``path`` (checked by :func:`check`), make it and mark it as ``command``'s."""
    if path.is_dir():
        for child in path.iterdir():
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child)
            else:
                child.unlink()
    path.mkdir(parents=True, exist_ok=True)
    (path / MARKER).write_text(f"hil {command}\n", encoding="utf-8")
    return path


def write_scenario(folder: Path, scenario: Any) -> Path:
    """The scenario a command ran, resolved whole (every table and key, any ``base`` merged
    in; :func:`hil.scenario.resolved_dict`), into ``folder`` as a run folder holds it."""
    controller, _, context = build_loop(scenario)
    path = folder / layout.SCENARIO_RESOLVED
    path.write_text(dumps_toml(resolved_dict(scenario, controller, context)), encoding="utf-8")
    return path

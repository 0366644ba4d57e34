"""The folder a command writes is new, or replaced whole (hil.folder.claim).

A folder that already holds an older run's files is refused by every command that writes
under --out, with one line naming --out and exit 2, before anything runs: the old files stay
as they were and nothing is added beside them. ``--force`` replaces such a folder whole (no
old file is left beside the new ones), and never deletes a folder that no hil command wrote.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hil.cli import main
from hil.errors import BAD_INPUT
from hil.folder import claim

S = "paper_tracking"
OLD = "report.html"  # an older run's report: the stale file a reused folder kept beside a new run


def _old_run(folder: Path) -> Path:
    """A folder holding what an older run left: its summary and its report."""
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text("{}")
    (folder / OLD).write_text("<p>old D 109.8 ms</p>")
    return folder


# Each command that writes under --out; OUT is the folder of an older run, A and B two folders.
COMMANDS = [
    ["run", "--duration", "1", "--out", "OUT"],
    ["sim", S, "--duration", "0.05", "--out", "OUT"],
    ["sweep", S, "--ts", "0.01", "--delay", "0", "--duration", "0.05", "--out", "OUT"],
    ["margin", S, "--seeds", "1", "--duration", "0.05", "--out", "OUT"],
    ["paper", "--quick", "--out", "OUT"],
    ["compare", "A", "B", "--out", "OUT"],
    ["fleet", S, "--robots", "1", "--duration", "1", "--out", "OUT"],
    ["drives", "--no-record", "--duration", "0.1", "--out", "OUT"],
    ["drives", "--duration", "0.1", "--record", "OUT"],
    ["certify", S, "--ts", "0.001", "--delay", "0", "--out", "OUT"],
    ["report", "A", "--out", "OUT"],
    ["can-load", "--rate", "100", "--bitrate", "500000", "--out", "OUT"],
    ["can-dbc", "--out", "OUT"],
]


@pytest.mark.parametrize("argv", COMMANDS, ids=lambda a: a[0])
def test_a_folder_holding_a_run_is_refused_before_anything_runs(
    argv: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _old_run(tmp_path / "out")
    before = sorted(p.name for p in out.iterdir())
    args = [{"OUT": str(out), "A": str(tmp_path), "B": str(tmp_path)}.get(a, a) for a in argv]
    assert main(args) == BAD_INPUT
    lines = capsys.readouterr().err.strip().splitlines()
    where = "--record" if "--record" in argv else "--out"  # the option that named the folder
    assert len(lines) == 1 and where in lines[0] and "--force" in lines[0], lines
    assert OLD in lines[0]  # the line says what is there
    assert sorted(p.name for p in out.iterdir()) == before  # nothing written, nothing removed


def test_force_replaces_the_folder_whole(tmp_path: Path) -> None:
    out = _old_run(tmp_path / "out")
    (out / "plots").mkdir()
    (out / "plots" / "old.png").write_bytes(b"old")
    argv = ["sim", S, "--duration", "0.05", "--out", str(out), "--force"]
    assert main(argv) == 0
    names = {p.name for p in out.iterdir()}
    assert OLD not in names and "plots" not in names  # no stale file beside the new ones
    assert {"trace.csv", "summary.json", "scenario.resolved.toml", claim.MARKER} <= names
    assert json.loads((out / "summary.json").read_text())["samples"] > 0  # the new run's


def test_a_forced_folder_is_one_hil_wrote_never_the_users(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "chapter1.tex").write_text("mine")
    argv = ["can-load", "--rate", "100", "--bitrate", "500000", "--out", str(out), "--force"]
    assert main(argv) == BAD_INPUT
    assert "no hil command wrote" in capsys.readouterr().err
    assert (out / "chapter1.tex").read_text() == "mine"


def test_a_folder_a_command_wrote_is_refused_for_the_next_and_forced_again(
    tmp_path: Path,
) -> None:
    out = tmp_path / "load"
    argv = ["can-load", "--rate", "100", "--bitrate", "500000", "--out", str(out)]
    assert main(argv) == 0
    assert main(argv) == BAD_INPUT  # its own output counts: no silent reuse
    assert main([*argv, "--force"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted([claim.MARKER, "can_load.json"])

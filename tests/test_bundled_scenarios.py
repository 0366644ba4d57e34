"""The scenarios shipped inside the package: by name from any folder, listed by
``hil scenarios``, refused with the list of names when unknown (exit 2)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.bundled import bundled_dir, bundled_names, description, resolve_scenario
from hil.cli import main
from hil.errors import BadInputError

PAPER = [
    "paper_chattering",
    "paper_circle_then_stop_unified",
    "paper_compare_jiang1997",
    "paper_compare_jiang2001",
    "paper_stabilization",
    "paper_tracking",
]


def test_the_paper_scenarios_are_bundled_inside_the_package() -> None:
    import hil

    assert bundled_names() == PAPER
    assert bundled_dir() == Path(hil.__file__).parent / "scenarios"
    for name in PAPER:  # each opens with a comment naming the paper's figures it reproduces
        text = description(bundled_dir() / f"{name}.toml")
        assert "Figures" in text and text.endswith(".") and "\n" not in text


@pytest.mark.parametrize("arg", ["paper_tracking", "paper_tracking.toml"])
def test_hil_sim_by_name_from_another_folder(tmp_path: Path, arg: str) -> None:
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "sim", arg, "--duration", "0.5", "--out", str(out)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["samples"] == 500 and summary["interrupted"] is False
    resolved = (out / "scenario.resolved.toml").read_text()
    assert "paper_tracking.toml" in resolved  # provenance names the bundled file


def test_a_file_that_exists_wins_over_a_bundled_name(tmp_path: Path, monkeypatch) -> None:
    mine = (bundled_dir() / "paper_tracking.toml").read_text().replace("ts = 0.001", "ts = 0.002")
    (tmp_path / "paper_tracking.toml").write_text(mine)
    monkeypatch.chdir(tmp_path)
    assert resolve_scenario("paper_tracking.toml") == Path("paper_tracking.toml")
    assert resolve_scenario("paper_tracking") == bundled_dir() / "paper_tracking.toml"
    out = tmp_path / "out"
    args = ["sim", "paper_tracking.toml", "--duration", "0.5", "--out", str(out)]
    assert main(args) == 0
    assert json.loads((out / "summary.json").read_text())["ts"] == 0.002


def test_hil_scenarios_lists_every_bundled_name(capsys) -> None:
    assert main(["scenarios"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split()[0] for line in lines] == PAPER
    assert all(len(line.split(None, 1)) == 2 for line in lines)  # each with a description
    assert main(["scenarios", "--path", "paper_tracking"]) == 0
    assert capsys.readouterr().out.strip() == str(bundled_dir() / "paper_tracking.toml")


@pytest.mark.parametrize("command", ["sim", "sweep", "certify", "run"])
def test_an_unknown_name_is_bad_input_naming_the_bundled_ones(tmp_path, capsys, command) -> None:
    out = [] if command == "certify" else ["--out", str(tmp_path / "o")]
    assert main([command, "paper_trackin", *out]) == 2
    assert not (tmp_path / "o").exists()  # refused before anything is written
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'paper_trackin'" in err[0]
    assert all(name in err[0] for name in PAPER)


def test_a_missing_path_is_not_looked_up_as_a_name(tmp_path: Path) -> None:
    with pytest.raises(BadInputError, match="no such file"):
        resolve_scenario(tmp_path / "paper_tracking.toml")


def test_help_says_how_to_use_bundled_scenarios(capsys) -> None:
    assert main(["scenarios", "--help"]) == 0
    text = capsys.readouterr().out
    assert "hil sim paper_tracking" in text and "path" in text
    assert main(["paper", "--help"]) == 0

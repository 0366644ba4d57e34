"""A scenario that starts from another (``base = "paper_tracking"``): the base's tables, each
key the file sets replacing the base's, and the folder's scenario.resolved.toml whole (no
``base`` left in it: it alone is the run's input)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from hil.bundled import bundled_path
from hil.cli import main
from hil.errors import BAD_INPUT, BadInputError
from hil.scenario import load_scenario

ONE_GAIN = """
base = "paper_tracking"

[controller]
rho = 0.5

[run]
duration = 0.05
"""


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(text)
    return path


def test_a_scenario_changes_one_gain_of_a_bundled_one(tmp_path: Path) -> None:
    paper = load_scenario(bundled_path("paper_tracking"))
    mine = load_scenario(_write(tmp_path, "mine.toml", ONE_GAIN))
    assert mine.controller == {**paper.controller, "rho": 0.5}
    assert mine.reference == paper.reference and mine.initial == paper.initial
    assert mine.timing == paper.timing and mine.limits == paper.limits
    assert mine.run.duration == 0.05 and paper.run.duration != 0.05


def test_the_folder_holds_the_resolved_scenario_whole(tmp_path: Path) -> None:
    path = _write(tmp_path, "mine.toml", ONE_GAIN)
    out = tmp_path / "sim"
    assert main(["sim", str(path), "--out", str(out)]) == 0
    resolved = tomllib.loads((out / "scenario.resolved.toml").read_text())
    assert "base" not in resolved
    assert resolved["controller"]["rho"] == 0.5 and resolved["controller"]["m1"] == 0.5
    assert resolved["reference"]["kind"] == "circle" and resolved["initial"]["x"] == -1.0
    # It alone is the scenario: read back without its base, the same loop.
    again = load_scenario(out / "scenario.resolved.toml")
    assert again.controller["rho"] == 0.5 and again.initial == load_scenario(path).initial


def test_another_law_or_reference_kind_replaces_its_table_whole(tmp_path: Path) -> None:
    text = 'base = "paper_tracking"\n[controller]\nlaw = "jiang1997"\n'
    mine = load_scenario(_write(tmp_path, "pd.toml", text))
    assert mine.controller == {"law": "jiang1997"}  # none of the unified law's gains


def test_a_base_next_to_the_file_and_a_chain(tmp_path: Path) -> None:
    _write(tmp_path, "mid.toml", 'base = "paper_tracking"\n[controller]\nrho = 0.7\n')
    sub = tmp_path / "sub"
    sub.mkdir()
    top = _write(sub, "top.toml", 'base = "../mid.toml"\n[controller]\nlam = 2.0\n')
    sc = load_scenario(top)
    assert sc.controller["rho"] == 0.7 and sc.controller["lam"] == 2.0


@pytest.mark.parametrize(
    ("files", "says"),
    [
        ({"a.toml": 'base = "b.toml"\n', "b.toml": 'base = "a.toml"\n'}, "cycle"),
        ({"a.toml": 'base = "no_such_scenario"\n'}, "no_such_scenario"),
        ({"a.toml": "base = 3\n"}, "base must be"),
        ({"a.toml": 'base = "paper_tracking"\n[controller]\nnope = 1\n'}, "nope"),
    ],
)
def test_a_bad_base_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], files: dict[str, str], says: str
) -> None:
    for name, text in files.items():
        _write(tmp_path, name, text)
    with pytest.raises(BadInputError, match=says):
        load_scenario(tmp_path / "a.toml")
    assert main(["sim", str(tmp_path / "a.toml"), "--out", str(tmp_path / "o")]) == BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["sweep", "SC", "--ts", "0.01", "--delay", "0", "--duration", "0.2"],
        ["margin", "SC", "--seeds", "1", "--duration", "0.2", "--k-max", "2"],
    ],
    ids=lambda a: a[0],
)
def test_sweep_and_margin_write_the_scenario_they_ran_whole(
    tmp_path: Path, argv: list[str]
) -> None:
    path = _write(tmp_path, "mine.toml", ONE_GAIN)
    out = tmp_path / "out"
    assert main([str(path) if a == "SC" else a for a in argv] + ["--out", str(out)]) in (0, 1)
    resolved = tomllib.loads((out / "scenario.resolved.toml").read_text())
    assert "base" not in resolved and resolved["controller"]["rho"] == 0.5
    assert resolved["reference"]["kind"] == "circle" and resolved["initial"]["x"] == -1.0

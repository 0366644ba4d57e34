"""tools.same_figures: what it calls a moved figure, on folders built for the purpose.

The tool's whole run (three recordings, two analyses each) is a check run by hand
(docs/architecture.md, "A refactoring moves no figure"); here its judgement is held to known
answers: a changed PNG or summary value is a moved figure, a new summary key is named, the
killed run's rewritten recording and the report's wording are not figures, and a raw copy keeps
only what the services and the recorder wrote.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tools.same_figures import compare, raw_copy, summary_changes

SUMMARY = {"timing": {"sample_to_apply_can": {"count": 2510, "p50_us": 1591.864}}, "samples": 9}


def folder(path: Path, **changed: bytes) -> Path:
    path.mkdir(parents=True)
    files = {
        "summary.json": json.dumps(SUMMARY).encode(),
        "report_latency.png": b"\x89PNG one",
        "trace.csv": b"t,x\n0,0\n",
        "recording.mcap": b"MCAP whole",
        "report.md": b"# the words",
        **changed,
    }
    for name, data in files.items():
        (path / name).write_bytes(data)
    return path


def test_identical_folders_have_no_moved_figure(tmp_path: Path) -> None:
    c = compare(folder(tmp_path / "a"), folder(tmp_path / "b"))
    assert c.figures_differ("zenoh") == []
    assert len(c.same) == 5 and c.different == [] and c.summary_changes == []


def test_a_changed_plot_is_a_moved_figure(tmp_path: Path) -> None:
    c = compare(folder(tmp_path / "a"), folder(tmp_path / "b", **{"report_latency.png": b"x"}))
    assert c.figures_differ("zenoh") == ["report_latency.png"]


def test_a_changed_summary_value_is_named_by_its_key(tmp_path: Path) -> None:
    moved = json.loads(json.dumps(SUMMARY))
    moved["timing"]["sample_to_apply_can"]["count"] = 2511
    moved["device"] = {"path": "zenoh"}
    c = compare(
        folder(tmp_path / "a"),
        folder(tmp_path / "b", **{"summary.json": json.dumps(moved).encode()}),
    )
    assert c.figures_differ("can") == ["summary.json"]
    assert c.summary_changes == ["+ /device", "~ /timing/sample_to_apply_can/count: 2510 -> 2511"]


@pytest.mark.parametrize(("name", "moved"), [("killed", []), ("zenoh", ["recording.mcap"])])
def test_only_the_killed_runs_recording_is_set_aside(tmp_path: Path, name, moved) -> None:
    rewritten = {"recording.mcap": b"MCAP rewritten", "report.md": b"# other words"}
    c = compare(folder(tmp_path / "a"), folder(tmp_path / "b", **rewritten))
    assert c.figures_differ(name) == moved
    assert sorted(c.different) == ["recording.mcap", "report.md"]


def test_a_figure_gone_after_is_a_moved_figure(tmp_path: Path) -> None:
    b = folder(tmp_path / "b")
    (b / "trace.csv").unlink()
    c = compare(folder(tmp_path / "a"), b)
    assert c.only_base == ["trace.csv"] and c.figures_differ("zenoh") == ["trace.csv"]


def test_the_raw_copy_keeps_what_the_services_and_the_recorder_wrote(tmp_path: Path) -> None:
    src = folder(
        tmp_path / "a", **{"plant.hoplog": b"h", "series.npz": b"n", "recovered.json": b"{}"}
    )
    raw_copy(src, tmp_path / "raw")
    assert sorted(f.name for f in (tmp_path / "raw").iterdir()) == [
        "plant.hoplog",
        "recording.mcap",
    ]


def test_summary_changes_of_nested_lists_and_removed_keys() -> None:
    assert summary_changes({"a": [1, 2], "b": 1}, {"a": [1, 3]}) == [
        "~ /a: [1, 2] -> [1, 3]",
        "- /b",
    ]

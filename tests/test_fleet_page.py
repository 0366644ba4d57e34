"""The fleet's page: fleet.md and fleet.html give every number formatted in
its unit, fleet.png's legend covers no bar, and each robot's folder gets its report.html from
the fleet report itself (``hil fleet`` writes it; tests/test_fleet.py runs a real fleet)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from hil.analysis import fleet_report
from hil.analysis.report.build import folder_verdict
from hil.folder import load_folder
from tests.synthetic_folder import write_synthetic_folder

#: A raw float: more than four decimals (0.012121212121212121, 2312.121212121212).
RAW_FLOAT = re.compile(r"\d\.\d{5,}")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, fleet_report.FleetSummary]:
    """Three robots' run folders; robot2 lost 10 ms of commands, and robot3's command age p99
    is a float as an exact percentile gives it."""
    out = tmp_path_factory.mktemp("fleet")
    for i, stall in ((1, None), (2, (1.0, 0.01)), (3, None)):
        folder = write_synthetic_folder(
            out / f"robot{i}", run=True, duration=2.0, seed=i, stall=stall
        )
        path = folder / "summary.json"
        summary = json.loads(path.read_text())
        # as its hil run judged it
        summary["verdict"] = folder_verdict(load_folder(folder)).as_dict()
        if i == 3:
            summary["timing"]["command_age_zenoh"]["p99_us"] = 2312.121212121212
        path.write_text(json.dumps(summary))
    summary = fleet_report.write(out, {"robot1": 0, "robot2": 0, "robot3": 0}, {})
    return out, summary


def test_the_fleet_page_formats_every_number(fleet) -> None:
    out, _ = fleet
    for page in ("fleet.md", "fleet.html"):
        text = (out / page).read_text()
        assert not RAW_FLOAT.search(text), (page, RAW_FLOAT.search(text))
        assert "True" not in text and "None" not in text, page
    md = (out / "fleet.md").read_text()
    assert "| [robot3](robot3/report.html) | PASS | " in md and "| 2312 |" in md, md
    assert "samples without a command" in md.splitlines()[6]  # a column of the robots' table


def test_the_fleet_page_answers_first_and_links_each_robots_report(fleet) -> None:
    out, _ = fleet
    html = (out / "fleet.html").read_text()
    assert html.index('class="verdict ok"') < html.index("<table>") < html.index("<img")
    for i in (1, 2, 3):
        assert f'href="robot{i}/report.html"' in html
        # written by the fleet report itself, no `hil report` by hand
        assert (out / f"robot{i}" / "report.html").is_file()
        judged = json.loads((out / f"robot{i}" / "report.json").read_text())["verdict"]
        assert judged["outcome"] == "PASS"  # the verdict the robot's run judged


def test_the_legend_covers_no_bar(fleet) -> None:
    _, summary = fleet
    fig = fleet_report.figure(summary)
    fig.canvas.draw()
    ax = fig.axes[0]
    legend = ax.get_legend().get_window_extent()
    bars = [p.get_window_extent() for p in ax.patches]
    assert len(bars) == 3
    assert not any(legend.overlaps(b) for b in bars), (legend, bars)
    markers = ax.lines[0].get_window_extent()
    assert not legend.overlaps(markers)

"""The pages as a reader sees them: report.html, compare.html, sweep.html, fleet.html and
paper.html rendered by headless Chromium at 1280 px (tools/screenshot.py). Each answers first,
fits the width, and stays a page one scrolls, not a wall (the run report was 10,500 px tall
before its figures shared rows and its long tables were folded)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hil.cli import main
from tests.synthetic_folder import write_synthetic_folder
from tools.screenshot import screenshot

#: Taller than this and a reader loses the page (px at 1280 wide).
MAX_HEIGHT = 9_000

pytestmark = pytest.mark.skipif(
    shutil.which("chromium") is None, reason="no chromium (.ci/run installs it)"
)


def _fits(png: Path) -> tuple[int, bool]:
    img = np.asarray(Image.open(png).convert("RGB"))
    background = img[-1, -1]
    right_edge = img[:, -8:]  # content running off the right: the page is wider than 1280 px
    return img.shape[0], bool((right_edge == background).all())


def test_the_run_report_answers_first_and_fits_the_screen(tmp_path: Path) -> None:
    folder = write_synthetic_folder(tmp_path / "run", run=True, delay=0.0005, duration=4.0)
    assert main(["report", str(folder), "--no-ideal"]) == 0
    height = screenshot(folder / "report.html", tmp_path / "report.png")
    h, fits = _fits(tmp_path / "report.png")
    assert height == h and h < MAX_HEIGHT and fits, (h, fits)


def test_the_compare_page_fits_the_screen(tmp_path: Path) -> None:
    a = write_synthetic_folder(tmp_path / "a", run=True, delay=0.0005, duration=2.0)
    b = write_synthetic_folder(tmp_path / "b", run=True, delay=0.002, duration=2.0)
    assert main(["compare", str(a), str(b), "--out", str(tmp_path / "cmp")]) == 0
    screenshot(tmp_path / "cmp" / "compare.html", tmp_path / "compare.png")
    h, fits = _fits(tmp_path / "compare.png")
    assert h < MAX_HEIGHT and fits, (h, fits)


def test_the_sweep_page_answers_first_and_fits_the_screen(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    args = ["sweep", "paper_tracking", "--duration", "1", "--ts", "0.005,0.02", "--delay", "0,0.01"]
    assert main([*args, "--out", str(out)]) == 0
    page = (out / "sweep.html").read_text()
    assert page.index('class="answer') < page.index('class="heat"') < page.index("<h2>Results")
    height = screenshot(out / "sweep.html", tmp_path / "sweep.png")
    h, fits = _fits(tmp_path / "sweep.png")
    assert height == h and h < MAX_HEIGHT and fits, (h, fits)


def test_the_fleet_page_answers_first_and_fits_the_screen(tmp_path: Path) -> None:
    from hil.analysis import fleet_report

    out = tmp_path / "fleet"
    for i in (1, 2):
        write_synthetic_folder(out / f"robot{i}", run=True, duration=1.0, seed=i)
    fleet_report.write(out, {"robot1": 0, "robot2": 0}, {})
    page = (out / "fleet.html").read_text()
    assert page.index('class="verdict') < page.index("<table>") < page.index("<img")
    height = screenshot(out / "fleet.html", tmp_path / "fleet.png")
    h, fits = _fits(tmp_path / "fleet.png")
    assert height == h and h < MAX_HEIGHT and fits, (h, fits)


def test_the_paper_page_answers_first_and_fits_the_width(tmp_path: Path) -> None:
    """hil paper's page from its own writers on 2 s runs (the page, not the claims)."""
    from hil.bundled import bundled_dir
    from hil.paper import FIGURE_GROUPS, PAPER_HTML, RUNS, _write_table
    from hil.scenario import load_scenario
    from hil.sim import simulate

    results = {
        name: simulate(
            load_scenario(bundled_dir() / f"paper_{name}.toml").with_overrides(duration=2.0)
        )
        for name in RUNS
    }
    for _, write in FIGURE_GROUPS:
        write(results, tmp_path)
    _write_table(tmp_path, results, quick=True, interrupted=False)
    page = (tmp_path / PAPER_HTML).read_text()
    assert page.index('class="verdict') < page.index("Measured figures") < page.index("<img")
    screenshot(tmp_path / PAPER_HTML, tmp_path / "paper.png")
    _, fits = _fits(tmp_path / "paper.png")
    assert fits  # 19 figures two to a row: a page one scrolls, but never wider than 1280 px

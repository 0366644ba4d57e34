"""``hil paper``'s page: paper.html beside the PNGs and table.md opens with
the paper's claims checked, draws a switching torque as the run report does (its envelope and
duty per bin, not raw chattering), and labels each quantity in its unit once (τ1 in m/s², τ2 in
rad/s²: the normalized inputs of model (1), never "N m")."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from hil.analysis.report.content import SIGNALS as REPORT_SIGNALS
from hil.bundled import bundled_dir
from hil.paper import FIGURE_GROUPS, PAPER_HTML, RUNS, _write_table, axis_label
from hil.scenario import load_scenario
from hil.sim import simulate


@pytest.fixture(scope="module")
def paper(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The paper's six runs, 3 s each (as --quick, shorter: the page, not the claims), their
    figures and table written by hil.paper's own writers."""
    out = tmp_path_factory.mktemp("paper")
    results = {}
    for name in RUNS:
        sc = load_scenario(bundled_dir() / f"paper_{name}.toml")
        results[name] = simulate(sc.with_overrides(duration=3.0))
    for _, write in FIGURE_GROUPS:
        write(results, out)
    _write_table(out, results, quick=True, interrupted=False)
    return out


def test_the_page_opens_with_the_claims_checked(paper: Path) -> None:
    html = (paper / PAPER_HTML).read_text()
    first = html.index('class="verdict')
    assert first < html.index("check of the paper&#x27;s claim") < html.index("Measured figures")
    assert html.index("Measured figures") < html.index("<img")
    assert len([p for p in paper.glob("fig*.png")]) == html.count("<img") == 19
    md = (paper / "table.md").read_text()
    assert md.index("## Checks of the paper's claims") < md.index("## Measured figures")


def test_a_switching_torque_is_drawn_as_its_envelope(paper: Path) -> None:
    for name in ("fig05_tracking_tau1", "fig06_tracking_tau2", "fig13_chattering_tau1"):
        with open(paper / f"{name}.csv") as f:
            header = next(csv.reader(f))
        assert {"robot_min", "robot_max", "robot_mean", "t_bin_s"} <= set(header), header
    with open(paper / "fig03_tracking_v.csv") as f:  # a velocity stays a line
        assert "robot_min" not in next(csv.reader(f))


def test_each_quantity_has_one_unit_on_every_page(paper: Path) -> None:
    for col in ("v", "omega", "tau1", "tau2"):
        assert axis_label(col) == REPORT_SIGNALS[col]  # the paper's axes, the report's tables
    assert axis_label("tau1") == "τ1 [m/s²]" and axis_label("tau2") == "τ2 [rad/s²]"
    for page in ("table.md", PAPER_HTML):
        text = (paper / page).read_text()
        assert "N m" not in text and "max abs" not in text and "phi1" not in text, page
        assert "max |τ1| [m/s²]" in text.replace("\\|", "|"), page

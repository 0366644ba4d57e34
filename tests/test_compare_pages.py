"""``hil compare`` says what moved by what matters: the figures the verdicts'
reasons name first, then figures against their limits or thresholds, never the relative change
of numbers at the noise level; "why B" lists every reason of B's verdict; the sliding variables
of (10) are explained only where a compared law has them (hil.law.facts.Law)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from hil.analysis.report.compare import most_moved
from hil.cli import main
from hil.verdict import Verdict
from tests.synthetic_folder import write_synthetic_folder

SLIDING_WORDS = "are the sliding variables of (10)"


@pytest.fixture(scope="module")
def compared(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A clean run (A) against one that lost 250 ms of commands on the wire (B): B's verdict
    has three reasons (certificate, samples without a command, lost messages); neither folder's
    summary.json holds a verdict (the report alone judges them), as a report-only folder."""
    tmp = tmp_path_factory.mktemp("cmp")
    a = write_synthetic_folder(tmp / "a", run=True, delay=0.0005, duration=2.0)
    b = write_synthetic_folder(tmp / "b", run=True, delay=0.0005, duration=2.0, stall=(1.0, 0.25))
    assert main(["compare", str(a), str(b), "--out", str(tmp / "out")]) == 0
    assert main(["report", str(b), "--no-ideal"]) == 1  # the verdict the report gives B
    return {
        "cmp": json.loads((tmp / "out" / "compare.json").read_text()),
        "md": (tmp / "out" / "compare.md").read_text(),
        "b_verdict": json.loads((b / "report.json").read_text())["verdict"],
    }


def test_what_decided_the_verdict_is_listed_first(compared: dict) -> None:
    head, verdict = compared["cmp"]["headline"], compared["b_verdict"]
    assert head["lines"][0] == "Verdict: A PASS, B FAIL."  # was "A n/a, B n/a"
    assert len(verdict["reasons"]) == 3
    moved = [r[0] for r in head["most_moved"]]
    # samples without a command (12.5 % against a 1 % threshold) decided it: it heads the list,
    # with D (against D*) and the lost messages, the other reasons' figures, right after
    assert moved[0] == "timing.samples_without_command_rate", moved
    assert set(moved[:3]) == {
        "timing.samples_without_command_rate",
        "certificate.d_max_s",
        "verdict.lost_messages_rate",
    }, moved
    first = head["most_moved"][0]
    assert first[6] == "threshold 1 %" and first[7].startswith("the verdict: "), first


def test_why_b_lists_every_reason_whole(compared: dict) -> None:
    lines, verdict = compared["cmp"]["headline"]["lines"], compared["b_verdict"]
    why = [line for line in lines if line.startswith("Why B")]
    assert len(why) == 1 and why[0].startswith("Why B, 3 reasons: (1) certificate not held")
    for reason in verdict["reasons"]:
        assert reason.split("; ")[0].split(" (")[0] in why[0], (reason, why[0])
    assert "(…)" not in why[0]  # never a sentence cut mid-way


def test_numbers_at_the_noise_level_never_top_the_list() -> None:
    """Position errors of 2e-12 and 5e-12 m (a 150 % relative change of numerical noise)
    against max |v| / φ1 moving from 0.50 to 0.60 and samples without a command from 0 to
    0.5 % of a 1 % threshold: the noise is not listed at all."""
    rows = [
        ["tracking.final_position_error", 2e-12, 5e-12, 3e-12],
        ["summary.final_heading_error", 1e-13, 4e-13, 3e-13],
        ["max_over_limit.v", 0.5, 0.6, 0.1],
        ["timing.samples_without_command_rate", 0.0, 0.005, 0.005],
        ["messages.state.sent", 1000.0, 1010.0, 10.0],
    ]
    verdict = Verdict(thresholds={"max_samples_without_command_ratio": 0.01})
    moved = [r[0] for r in most_moved(rows, (verdict, verdict))]
    assert moved == [
        "timing.samples_without_command_rate",  # 0.5 of its threshold
        "max_over_limit.v",  # 0.1 of φ1
        "messages.state.sent",  # no limit: by its relative change
    ], moved


def test_the_sliding_variables_are_explained_only_for_a_law_that_has_them(
    tmp_path: Path, compared: dict
) -> None:
    law = "tests.example_user_controller:SaturatedPD"  # a PD loop: no v~, w~
    sims = []
    for ts in ("0.002", "0.004"):
        out = tmp_path / f"pd{ts}"
        args = ["sim", "paper_tracking", "--law", law, "--duration", "1", "--ts", ts]
        assert main([*args, "--out", str(out)]) == 0
        sims.append(str(out))
    assert main(["compare", *sims, "--out", str(tmp_path / "cmp")]) == 0
    assert SLIDING_WORDS not in (tmp_path / "cmp" / "compare.md").read_text()
    assert SLIDING_WORDS not in (tmp_path / "cmp" / "compare.html").read_text()
    assert SLIDING_WORDS in compared["md"]  # the unified law has them: said


def test_the_figures_are_named_in_the_papers_symbols(compared: dict) -> None:
    """The compare page's names (its first column) say |ω|, τ1, φ2, never "max abs omega";
    the keys (compare.json's, second column) stay as scripts read them."""
    ascii_names = re.compile(r"\b(phi[12]|varpi[12]|omega|tau[12]|max abs)\b")
    names = [line.split(" | ")[0] for line in compared["md"].splitlines() if line.startswith("| ")]
    assert names and not [n for n in names if ascii_names.search(n)], names
    assert any("max \\|ω\\|" in n for n in names), names

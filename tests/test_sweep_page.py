"""sweep.html: the break point first, a heat map of the break over Ts x delay, the results
table with units, from the same document as sweep.json; and ``hil sweep`` writes it."""

from __future__ import annotations

import html
import json
import re
import subprocess
import sys
from pathlib import Path

from hil.sweep.page import COLOURS, heat_cells, sweep_html
from tests.page_tables import numbers_without_unit, tables, unglossed


def _row(ts: float, delay: float, over_v: float, violations: int, seed: int = 0) -> dict:
    return {
        "ts": ts, "delay": delay, "jitter": 0.0, "seed": seed, "age": ts + delay,
        "rms_position_error": 0.01, "max_abs_v": 1.6 * over_v, "max_abs_omega": 1.0,
        "overshoot_v": over_v, "overshoot_omega": 0.2, "violations": violations,
        "certified": None,
    }  # fmt: skip


DOC = {
    "scenario_file": "my <scenario>.toml",
    "law": "my_law:Law",
    "duration": 2.0,
    "grid": {"ts": [0.001, 0.01], "delay": [0.0, 0.05], "jitter": [0.0], "seeds": 2},
    "rows": [
        _row(0.001, 0.0, 0.50, 0),
        _row(0.001, 0.0, 0.55, 0, seed=1),
        _row(0.01, 0.0, 0.95, 0),
        _row(0.001, 0.05, 0.70, 0),
        _row(0.01, 0.05, 1.30, 12),
    ],
    "break_point": {
        "violating_points": 1,
        "first": {"ts": 0.01, "delay": 0.05, "jitter": 0.0, "seed": 0},
    },
    "certificate": {"first_uncertified": None},
    "figures": [{"title": "max |v| / phi1 against Ts", "png": "a.png", "data": "a.csv"}],
}


def test_heat_cells_take_the_worst_over_seeds_and_mark_the_break() -> None:
    cells = heat_cells(DOC["rows"])
    assert cells[(0.001, 0.0)] == (0.55, False)  # the worse of the two seeds
    assert cells[(0.01, 0.0)] == (0.95, False)
    assert cells[(0.01, 0.05)] == (1.30, True)


def test_the_page_answers_first_then_maps_and_tabulates() -> None:
    page = sweep_html(DOC)
    answer = page.index("first break at Ts = 0.01 s with a delay of 0.05 s")
    assert answer < page.index("<h2>Where the limits break") < page.index("<h2>Results")
    assert "my &lt;scenario&gt;.toml" in page and "<scenario>" not in page
    cells = re.findall(r'<td style="background:(#\w+)">([^<]*)</td>', page)
    assert (COLOURS["broke"], "1.30 ✗") in cells
    assert (COLOURS["near"], "0.95") in cells and (COLOURS["inside"], "0.55") in cells
    for header in ("Ts [s]", "delay [s]", "max |v| [m/s]", "RMS position error, last 10 % [m]"):
        assert f"<th>{header}</th>" in page.replace("&#x27;", "'")
    table = page[page.index("<h2>Results") : page.index("<h2>Figures")]
    assert table.count("<tr") == 1 + len(DOC["rows"])  # header + one row per loop
    assert '<img src="a.png"' in page


def test_hil_sweep_writes_the_page(tmp_path: Path) -> None:
    out = tmp_path / "sw"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "hil",
            "sweep",
            "paper_tracking",
            "--duration",
            "1",
            "--ts",
            "0.005,0.02",
            "--delay",
            "0,0.01",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert f"sweep: {out / 'sweep.html'}" in proc.stdout
    page = (out / "sweep.html").read_text()
    doc = json.loads((out / "sweep.json").read_text())
    assert page.count('<td style="background:') == 4  # the 2 x 2 heat map
    table = page[page.index("<h2>Results") : page.index("<h2>Figures")]
    assert table.count("<tr") == 1 + len(doc["rows"]) == 5
    for f in doc["figures"]:
        assert (out / f["png"]).is_file() and f'src="{f["png"]}"' in page
    # a unit beside every number, a sentence beside every symbol, the scenario's own limits
    assert len(tables(page)) == 2 and not numbers_without_unit(page), numbers_without_unit(page)
    words = html.unescape(re.sub(r"<[^>]+>", " ", page))
    assert not unglossed(words), unglossed(words)
    assert "|v| ≤ φ1 = 1.6 m/s and |ω| ≤ φ2 = 5.1 rad/s" in words

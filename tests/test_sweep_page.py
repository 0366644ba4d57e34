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
    "coverage": {"loops": 5, "covered": 5, "cut_short": 0, "not_run": 0},
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
    # the certificate's sentence names exactly the table's points where it does not hold
    no, run = _table_uncertified(page)
    sentence = _certificate_sentence(page)
    assert _said_uncertified(sentence, run) == no, (sentence, no)
    assert ("guarantees (2) at every" in sentence) is (not no), sentence


def _certificate_sentence(page: str) -> str:
    words = html.unescape(re.sub(r"<[^>]+>", " ", page))
    return next(s for s in re.split(r"(?<=\.)\s", words) if "The certificate" in s)


def _said_uncertified(sentence: str, ts_by_delay: dict[float, list[float]]) -> set:
    """The (Ts, delay) points the sentence says the certificate does not guarantee (2) at."""
    said = set()
    for delay, which in re.findall(r"delay = ([0-9.e-]+) s: (every Ts run|Ts = [^;]+ s)", sentence):
        d = float(delay)
        ts = ts_by_delay[d] if which == "every Ts run" else [
            float(x) for x in which[len("Ts = ") : -len(" s")].split(", ")
        ]  # fmt: skip
        said |= {(t, d) for t in ts}
    return said


def _table_uncertified(page: str) -> tuple[set, dict[float, list[float]]]:
    """The results table's points whose "certificate holds" cell is NO, and the Ts run per delay."""
    (_, results) = tables(page)
    head = results[0]
    i_ts, i_d = head.index("Ts [s]"), head.index("delay [s]")
    i_c = head.index("certificate holds (age ≤ D*)")
    no, run = set(), {}
    for row in results[1:]:
        ts, d = float(row[i_ts]), float(row[i_d])
        run.setdefault(d, []).append(ts)
        if row[i_c] == "NO":
            no.add((ts, d))
    return no, {d: sorted(set(v)) for d, v in run.items()}


def test_the_certificate_sentence_is_its_tables_no_points():
    """The page once said the certificate stops guaranteeing (2) "from Ts = 0.02 s, delay
    = 0.01 s" (the smallest age not certified) while its own table showed NO at Ts = 0.001 s,
    delay = 0.05 s (a larger age, a smaller Ts): the sentence now lists the table's points."""
    certified = {(0.001, 0.0): True, (0.02, 0.0): True, (0.001, 0.01): True,
                 (0.02, 0.01): False, (0.001, 0.05): False, (0.02, 0.05): False}  # fmt: skip
    rows = [{**_row(ts, d, 0.5, 0), "certified": c} for (ts, d), c in certified.items()]
    doc = {**DOC, "law": "unified", "rows": rows,
           "grid": {"ts": [0.001, 0.02], "delay": [0.0, 0.01, 0.05], "jitter": [0.0], "seeds": 1},
           "coverage": {"loops": 6, "covered": 6, "cut_short": 0, "not_run": 0},
           "break_point": {"violating_points": 0, "first": None},
           # the prediction over the grid, as sweep.json keeps it: not what the page says
           "certificate": {"first_uncertified": {"ts": 0.02, "delay": 0.01, "jitter": 0.0,
                                                 "age": 0.03}}}  # fmt: skip
    page = sweep_html(doc)
    sentence = _certificate_sentence(page)
    no, run = _table_uncertified(page)
    assert no == {(0.02, 0.01), (0.001, 0.05), (0.02, 0.05)}
    assert _said_uncertified(sentence, run) == no, sentence
    assert "from Ts" not in sentence and "3 of the 6 (Ts, delay) points run" in sentence
    assert "delay = 0.05 s: every Ts run" in sentence and "delay = 0.01 s: Ts = 0.02 s" in sentence

"""What a reader of a page (report.html, compare.html, sweep.html) needs beside each number and
each symbol of the paper: a unit, and a plain sentence.

:func:`numbers_without_unit` lists the numbers of a page's tables that nothing in their table
gives a unit: not their column's header (``[m/s]``, ``µs``, a ratio to a limit), not their row's
label, not a ``unit`` column. What is counted needs no unit beyond its noun (``sent``,
``samples without a command``): :data:`COUNTED` names those nouns. :func:`unglossed` lists the
symbols of the paper a page uses without the sentence that says what each one is.
"""

from __future__ import annotations

import re
from html.parser import HTMLParser

NUMBER = re.compile(r"^[-+]?(\d+(\.\d*)?|\.\d+)([eE][-+]?\d+)?( ✗)?$")
UNIT = re.compile(r"\[[^\]]+\]|µs|\bms\b|%|\blimit\b")
COUNTED = re.compile(
    r"\b(count|seed|sent|received|lost|duplicated|reordered|rejections|misses|samples|"
    r"messages|stalls)\b"
)

#: A symbol of the paper -> the words that say what it is (one of them must be on the page).
GLOSSES: dict[str, tuple[str, ...]] = {
    "(1)": ("Model (1) is normalized",),
    "(2)": (
        "The constraints (2) are the limits the law must never exceed",
        "(2) are the limits the law must keep",
        "Limits of (2), the bounds φ1, φ2 on the velocities and ϖ1, ϖ2 on the inputs",
    ),
    "(4)": ("The tracking errors (4) are",),
    "D*": (
        "D*: largest age the bound allows",
        "D*: the longest the paper's bound allows",
        "while no command is older than D*",
    ),
    "v~": ("are the sliding variables of (10)",),
}


class _Tables(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tables: list[list[list[str]]] = []
        self._row: list[str] | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "table":
            self.tables.append([])
        elif tag == "tr" and self.tables:
            self._row = []
            self.tables[-1].append(self._row)
        elif tag in ("td", "th") and self._row is not None:
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None and self._row is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)


def tables(page: str) -> list[list[list[str]]]:
    """Every table of the page: rows of cell texts, the header row first."""
    parser = _Tables()
    parser.feed(page)
    return [t for t in parser.tables if t]


def numbers_without_unit(page: str) -> list[str]:
    """``header / row label: number`` of each number whose unit its table does not give."""
    out = []
    for rows in tables(page):
        header = rows[0]
        if any(h.strip().lower() == "unit" for h in header):
            continue
        for row in rows[1:]:
            label = row[0]
            for j, cell in enumerate(row[1:], start=1):
                if not NUMBER.match(cell):
                    continue
                head = header[j] if j < len(header) else ""
                told = UNIT.search(head) or UNIT.search(label) or UNIT.search(header[0])
                if not (told or COUNTED.search(head) or COUNTED.search(label)):
                    out.append(f"{head or '?'} / {label}: {cell}")
    return out


def unglossed(text: str) -> list[str]:
    """The symbols of :data:`GLOSSES` that ``text`` uses without any of their glosses."""
    return [s for s, words in GLOSSES.items() if s in text and not any(w in text for w in words)]

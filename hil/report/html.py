"""Self-contained HTML that opens offline: inline CSS, figures as base64 PNG data URIs, no
script, no link. The sections and their text are hil.report.content's, as report.md's."""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable, Sequence
from typing import Any

from hil.report.content import fmt, sections
from hil.report.figures import Figure

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:1200px;padding:0 1em;color:#222;line-height:1.4}
.figs{display:grid;grid-template-columns:repeat(auto-fit,minmax(520px,1fr));gap:0 1.2em}
nav.toc{columns:2;font-size:.95em;margin:.5em 0 1em}nav.toc a{text-decoration:none}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;
text-align:left;font-variant-numeric:tabular-nums}th{background:#f4f4f4}
.ok{background:#e6f4e6;border:2px solid #3a3}.bad{background:#fbe9e9;border:2px solid #c33}
.unsure{background:#fff6dd;border:2px solid #c90}
.verdict{padding:.8em 1.2em;margin:1em 0}figure{margin:1em 0}img{max-width:100%}
figcaption{font-size:.9em;color:#555}code{background:#f4f4f4;padding:0 .2em}
"""


def esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{esc(fmt(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def figure(f: Figure, prefix: str = "report_") -> str:
    b64 = base64.b64encode(f.png).decode("ascii")
    caption = f" {esc(f.caption)}" if f.caption else ""
    return (
        f'<figure><img alt="{esc(f.title)}" src="data:image/png;base64,{b64}">'
        f"<figcaption>{esc(f.title)} (data: <code>{esc(prefix + f.name)}.csv</code>)"
        f"{caption}</figcaption></figure>"
    )


#: Tables longer than this are folded (a <details> the reader opens): the page answers first.
FOLD_ROWS = 12


def _folded(header: Sequence[str], rows: Sequence[Sequence[Any]], fold: str | None = None) -> str:
    if fold is None and len(rows) <= FOLD_ROWS:
        return table(header, rows)
    summary = fold or f"{len(rows)} rows: {', '.join(header)}"
    return f"<details><summary>{esc(summary)}</summary>{table(header, rows)}</details>"


def _grid(figures: list[str]) -> list[str]:
    return ['<div class="figs">', *figures, "</div>"] if len(figures) > 1 else figures


def render_html(data: dict[str, Any], figs: Sequence[Figure]) -> str:
    by_name = {f.name: f for f in figs}
    s = data["scenario"]
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{esc('Report: ' + data['folder'])}</title>",
        f"<style>{CSS}</style></head><body>",
        f"<h1>What timing did to the law: {esc(data['folder'])}</h1>",
    ]
    listed = list(sections(data))
    # the table of contents: a link to each section after the headline
    links = "".join(f'<li><a href="#{esc(x.id)}">{esc(x.title)}</a></li>' for x in listed[1:])
    for section in listed:
        parts.append(f'<section id="{esc(section.id)}">')
        if section.id == "headline":
            outcome = data["headline"]["verdict"]
            cls = {"PASS": "ok", "INCONCLUSIVE": "unsure"}.get(outcome, "bad")
            parts.append(f'<div class="verdict {cls}"><strong>{outcome}</strong>')
        else:
            parts.append(f"<h2>{esc(section.title)}</h2>")
        pending: list[str] = []  # figures in a row share a two-column grid
        for block in section.blocks:
            kind = block[0]
            if kind == "figure":
                if block[1] in by_name:
                    pending.append(figure(by_name[block[1]]))
                continue
            parts.extend(_grid(pending))
            pending = []
            if kind == "p":
                parts.append(f"<p>{esc(block[1])}</p>")
            elif kind == "list":
                parts.append("<ul>" + "".join(f"<li>{esc(t)}</li>" for t in block[1]) + "</ul>")
            elif kind == "table":
                parts.append(_folded(block[1], block[2], block[3]))
        parts.extend(_grid(pending))
        if section.id == "headline":
            parts += [
                "</div>",
                f"<p>{esc(data['kind'])} · law <code>{esc(s['law'])}</code> · "
                f"Ts {esc(fmt(s['ts']))} s · delay {esc(fmt(s['delay']))} s"
                f" · jitter {esc(fmt(s['jitter']))} s ({esc(s['jitter_kind'])})</p>",
                f'<nav class="toc"><strong>Contents</strong><ol>{links}</ol></nav>',
            ]
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts)

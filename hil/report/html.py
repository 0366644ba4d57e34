"""Self-contained HTML: inline CSS, figures as base64 PNG data URIs, no script, no link.

Opens offline: nothing in the page refers to a network resource.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Iterable, Sequence
from typing import Any

from hil.report.figures import Figure
from hil.report.markdown import SECTION_FIGURES, SECTION_TITLES, fmt, metric_rows

CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:1000px;color:#222;line-height:1.4}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .6em;
text-align:left;font-variant-numeric:tabular-nums}th{background:#f4f4f4}
.ok{background:#e6f4e6;border:2px solid #3a3}.bad{background:#fbe9e9;border:2px solid #c33}
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
    return (
        f'<figure><img alt="{esc(f.title)}" src="data:image/png;base64,{b64}">'
        f"<figcaption>{esc(f.title)} (data: <code>{esc(prefix + f.name)}.csv</code>)"
        "</figcaption></figure>"
    )


def render_html(data: dict[str, Any], figs: Sequence[Figure]) -> str:
    by_name = {f.name: f for f in figs}
    v = data["verdict"]
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{esc('Report: ' + data['folder'])}</title>",
        f"<style>{CSS}</style></head><body>",
        f"<h1>What timing did to the law: {esc(data['folder'])}</h1>",
        f"<p>{esc(data['kind'])} · law <code>{esc(data['scenario']['law'])}</code> · "
        f"Ts {esc(fmt(data['scenario']['ts']))} s · delay {esc(fmt(data['scenario']['delay']))} s"
        f" · jitter {esc(fmt(data['scenario']['jitter']))} s "
        f"({esc(data['scenario']['jitter_kind'])})</p>",
    ]
    cls = "ok" if v["ok"] else "bad"
    parts.append(f'<section id="verdict"><h2>{SECTION_TITLES["verdict"]}</h2>')
    parts.append(f'<div class="verdict {cls}"><strong>{"PASS" if v["ok"] else "FAIL"}</strong>')
    parts.append(
        table(
            ["item", "state"],
            [
                ["limits (2)", v["limits"]],
                ["certificate", v["certificate"]],
                ["deadline misses", v["deadline_misses"]],
                ["lost messages", v["lost_messages"]],
            ],
        )
    )
    if v["reasons"]:
        parts.append("<ul>" + "".join(f"<li>{esc(r)}</li>" for r in v["reasons"]) + "</ul>")
    parts.append("</div></section>")
    for section in data["sections"]:
        if section == "verdict":
            continue
        parts.append(f'<section id="{esc(section)}"><h2>{esc(SECTION_TITLES[section])}</h2>')
        for header, rows in metric_rows(data, section):
            parts.append(table(header, rows))
        for name in SECTION_FIGURES.get(section, ()):
            if name in by_name:
                parts.append(figure(by_name[name]))
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts)

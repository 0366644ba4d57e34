"""report.md: the same sections as the HTML (hil.report.content), figures as PNG files beside
it. The first lines after the title are the headline: the four answers and the verdict."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from hil.report.content import fmt, sections

__all__ = ["_md_table", "fmt", "render_markdown"]


def _cell(value: Any) -> str:
    return fmt(value).replace("|", "\\|").replace("\n", " ")


def _md_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def render_markdown(data: dict[str, Any], files: Sequence[dict[str, str]]) -> str:
    by_name = {f["name"]: f for f in files}
    s = data["scenario"]
    out = [f"# What timing did to the law: {data['folder']}", ""]
    listed = list(sections(data))
    for section in listed:
        if section.id != "headline":
            out += [f"## {section.title}", ""]
        for block in section.blocks:
            kind = block[0]
            if kind == "p":
                out += [block[1], ""]
            elif kind == "list":
                out += [f"- {text}" for text in block[1]] + [""]
            elif kind == "table":
                out += [_md_table(block[1], block[2]), ""]
            elif kind == "figure":
                f = by_name.get(block[1])
                if f:
                    out += [
                        f"![{f['title']}]({f['png']})",
                        "",
                        f"Data: [{f['data']}]({f['data']})"
                        + (f". {f['caption']}" if f.get("caption") else ""),
                        "",
                    ]
        if section.id == "headline":
            out += [
                f"{data['kind']} · law `{s['law']}` · Ts {fmt(s['ts'])} s · delay "
                f"{fmt(s['delay'])} s · jitter {fmt(s['jitter'])} s ({s['jitter_kind']})",
                "",
                "Contents: " + " · ".join(x.title for x in listed[1:]),
                "",
            ]
    return "\n".join(out) + "\n"

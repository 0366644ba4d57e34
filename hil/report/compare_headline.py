"""What ``hil compare`` says first: the differences that matter, with units.

The verdicts, the command age D against D* and the limits of (2) of both folders, then the
figures that moved most (relative change, largest first). Every number is one the two folders
already hold (summary.json, the measurement, the sampling effects of their traces).
"""

from __future__ import annotations

import math
from typing import Any

from hil.folder import RunFolder
from hil.report.compare_names import label_of, unit_of
from hil.verdict import short_reason

LIMIT_RATIOS = (("v", "|v|/φ1"), ("omega", "|ω|/φ2"), ("tau1", "|τ1|/ϖ1"), ("tau2", "|τ2|/ϖ2"))
#: How many of the most-moved figures the headline lists.
MOST_MOVED = 8
#: How much of a verdict's first reason the headline quotes (the reports have all of it).
WHY_CHARS = 200


def _outcome(folder: RunFolder) -> str:
    v = folder.summary.get("verdict")
    if isinstance(v, dict) and v.get("outcome"):
        return str(v["outcome"])
    held = folder.summary.get("limits_held")
    return "limits held" if held else ("limits broken" if held is False else "n/a")


def _ms(x: Any) -> str:
    return f"{x * 1e3:.3f} ms" if isinstance(x, int | float) and math.isfinite(x) else "n/a"


def _age(folder: RunFolder) -> str:
    c = folder.summary.get("certificate")
    if not isinstance(c, dict):
        return "D n/a"
    return f"D = {_ms(c.get('d_max_s'))} of D* = {_ms(c.get('d_star_s'))}"


def _why(folder: RunFolder) -> str | None:
    """The first reason of a verdict that is not PASS, up to its details."""
    v = folder.summary.get("verdict")
    if not isinstance(v, dict) or v.get("outcome") in (None, "PASS") or not v.get("reasons"):
        return None
    return short_reason(str(v["reasons"][0]), WHY_CHARS)


def most_moved(rows: list[list[Any]], n: int = MOST_MOVED) -> list[list[Any]]:
    """The rows whose value changed most relative to A (absolute change where A is 0)."""
    scored = []
    for key, a, b, diff in rows:
        if diff is None or not math.isfinite(diff) or diff == 0 or key in ("ts", "delay"):
            continue
        base = abs(a) if a else 1.0
        scored.append((abs(diff) / base, [key, a, b, diff, unit_of(key), label_of(key)]))
    scored.sort(key=lambda s: -s[0])
    out: list[list[Any]] = []
    seen = set()
    for _, row in scored:  # one figure under two keys (summary and tracking) is listed once
        if (row[5], row[1], row[2]) not in seen and len(out) < n:
            seen.add((row[5], row[1], row[2]))
            out.append(row)
    return out


def compare_headline(
    fa: RunFolder, fb: RunFolder, a: dict[str, float], b: dict[str, float], rows: list[list[Any]]
) -> dict[str, Any]:
    """The headline's lines and the most-moved table (see the module docstring)."""
    lines = [f"Verdict: A {_outcome(fa)}, B {_outcome(fb)}."]
    lines += [f"Why {n}: {why.rstrip('.')}." for n, f in (("A", fa), ("B", fb)) if (why := _why(f))]
    lines.append(
        f"Command age: A {_age(fa)}; B {_age(fb)} (D: the longest a command stayed in force "
        "after the sample it was computed from; D*: the longest the paper's bound allows "
        "while still guaranteeing the limits (2))."
    )
    limits = []
    for name, sym in LIMIT_RATIOS:
        ra, rb = a.get(f"max_over_limit.{name}"), b.get(f"max_over_limit.{name}")
        if ra is not None and rb is not None:
            limits.append(f"max {sym} {ra:.3f} → {rb:.3f}")
    if limits:
        lines.append(
            "Limits of (2), the bounds φ1, φ2 on the velocities and ϖ1, ϖ2 on the inputs "
            "the law must keep, as peak / limit from A to B (1 = at the limit): "
            + "; ".join(limits)
            + "."
        )
    return {"lines": lines, "most_moved": most_moved(rows)}

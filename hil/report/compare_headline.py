"""What ``hil compare`` says first: the differences that matter, with units.

The verdicts, the command age D against D* and the limits of (2) of both folders, then the
figures that moved most (relative change, largest first). Every number is one the two folders
already hold (summary.json, the measurement, the sampling effects of their traces).
"""

from __future__ import annotations

import math
from typing import Any

from hil.folder import RunFolder

LIMIT_RATIOS = (("v", "|v|/φ1"), ("omega", "|ω|/φ2"), ("tau1", "|τ1|/ϖ1"), ("tau2", "|τ2|/ϖ2"))
#: How many of the most-moved figures the headline lists.
MOST_MOVED = 8


def unit_of(key: str) -> str:
    """The unit of a compared figure, from its name."""
    last = key.rsplit(".", 1)[-1]
    if last.endswith("_us"):
        return "µs"
    if last.endswith("_s") or last in ("ts", "delay", "jitter", "duration"):
        return "s"
    if key.startswith("max_over_limit.") or last in ("held",):
        return "x limit" if key.startswith("max_over_limit.") else "yes=1"
    if "heading" in last:
        return "rad"
    if "position" in last or key.startswith("tracking."):
        return "m"
    if key.startswith("switching_rate."):
        return "1/s"
    if last.endswith(("_rate", "_share")) or key.startswith("saturation_share."):
        return "fraction"
    if last in ("max_abs_v", "v_bound"):
        return "m/s"
    if last in ("max_abs_omega", "omega_bound"):
        return "rad/s"
    return "count" if key.startswith(("messages.", "violations.")) else ""


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
    return f"D {_ms(c.get('d_max_s'))} of D* {_ms(c.get('d_star_s'))}"


def most_moved(rows: list[list[Any]], n: int = MOST_MOVED) -> list[list[Any]]:
    """The rows whose value changed most relative to A (absolute change where A is 0)."""
    scored = []
    for key, a, b, diff in rows:
        if diff is None or not math.isfinite(diff) or diff == 0 or key in ("ts", "delay"):
            continue
        base = abs(a) if a else 1.0
        scored.append((abs(diff) / base, [key, a, b, diff, unit_of(key)]))
    scored.sort(key=lambda s: -s[0])
    return [row for _, row in scored[:n]]


def compare_headline(
    fa: RunFolder, fb: RunFolder, a: dict[str, float], b: dict[str, float], rows: list[list[Any]]
) -> dict[str, Any]:
    """The headline's lines and the most-moved table (see the module docstring)."""
    lines = [
        f"Verdict: A {_outcome(fa)}, B {_outcome(fb)}.",
        f"Command age: A {_age(fa)}; B {_age(fb)} (D*: the largest age the paper's bound allows).",
    ]
    limits = []
    for name, sym in (
        ("v", "|v|/φ1"),
        ("omega", "|ω|/φ2"),
        ("tau1", "|τ1|/ϖ1"),
        ("tau2", "|τ2|/ϖ2"),
    ):
        ra, rb = a.get(f"max_over_limit.{name}"), b.get(f"max_over_limit.{name}")
        if ra is not None and rb is not None:
            limits.append(f"max {sym} {ra:.3f} → {rb:.3f}")
    if limits:
        lines.append("Limits of (2) (1 = at the limit): " + "; ".join(limits) + ".")
    return {"lines": lines, "most_moved": most_moved(rows)}

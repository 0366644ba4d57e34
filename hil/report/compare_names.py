"""What a compared figure is called on the page and in which unit, from its key.

The keys (``timing.hop_cmd_can.p99_us``, ``summary.max_abs_v``) stay what compare.json and
scripts use; a reader gets words and a unit beside each number instead.
"""

from __future__ import annotations

from hil.verdict import UNITS as SIGNAL_UNITS

#: Figures a reader looks for by name, in words (the paper's symbols glossed).
NAMES = {
    "ts": "Ts, the control period",
    "delay": "delay added to every command",
    "jitter": "jitter of the controller's wake-ups",
    "certificate.d_max_s": "D, the longest a command stayed in force",
    "certificate.d_star_s": "D*, the longest the paper's bound allows",
    "certificate.margin_s": "margin D* − D",
    "certificate.held": "certificate held (D ≤ D* and the design conditions)",
    "certificate.stalls": "stalls (commands in force above the stall threshold)",
    "certificate.v_bound": "largest |v| the bound allows",
    "certificate.omega_bound": "largest |ω| the bound allows",
    "max_over_limit.v": "max |v| / φ1 (the limit of (2) on v)",
    "max_over_limit.omega": "max |ω| / φ2 (the limit of (2) on ω)",
    "max_over_limit.tau1": "max |τ1| / ϖ1 (the limit of (2) on τ1)",
    "max_over_limit.tau2": "max |τ2| / ϖ2 (the limit of (2) on τ2)",
    "timing.startup_hold_s": "start-up hold: first command landed after the first sample",
    "timing.late_commands": "late commands (applied more than Ts after their sample)",
    "timing.late_commands_rate": "late commands, share of the samples",
    "timing.compute.p50_us": "controller compute time, p50",
    "timing.compute.p99_us": "controller compute time, p99",
    "timing.compute.max_us": "controller compute time, max",
    "band_p99.v_tilde": "band of v~ = v − α_v (p99 of |v~| once reached)",
    "band_p99.w_tilde": "band of w~ = ω − α_ω (p99 of |w~| once reached)",
}
#: Where a figure comes from, as its key's first part names it.
GROUPS = {
    "summary": "",
    "tracking": "",
    "timing": "",
    "messages": "messages",
    "violations": "plant steps beyond (2)",
    "switching_rate": "switching rate",
    "saturation_share": "share of samples at the limit",
}


def unit_of(key: str) -> str:
    """The unit of a figure, from its name ("count" for what is counted): the compare page's
    and the report's tables."""
    group, _, last = key.rpartition(".")
    if last.endswith("_us"):
        return "µs"
    if last.endswith("_hz"):
        return "Hz"
    if last.endswith("_s") or last in ("ts", "delay", "jitter", "duration"):
        return "s"
    if group == "max_over_limit":
        return "x limit"
    if last == "held":
        return "yes = 1"
    if "heading" in last:
        return "rad"
    if "position" in last or "deviation" in last or group == "tracking":
        return "m"
    if group == "switching_rate":
        return "1/s"
    if last.endswith(("_rate", "_share")) or group == "saturation_share":
        return "fraction"
    if last.startswith("max_abs_"):
        return SIGNAL_UNITS.get(last.removeprefix("max_abs_"), "")
    if last == "v_bound" or last == "v_tilde":
        return "m/s"
    if last in ("omega_bound", "w_tilde"):
        return "rad/s"
    return "" if last == "schema_version" else "count"


def label_of(key: str) -> str:
    """The figure in words: its name where it has one, else its key's words without the unit
    suffix (the unit column says it) and the group it belongs to."""
    if key in NAMES:
        return NAMES[key]
    parts = key.split(".")
    group = parts[0] if len(parts) > 1 else ""
    words = []
    for part in parts[1:] if group else parts:
        for suffix in ("_us", "_hz", "_s"):
            part = part.removesuffix(suffix)
        words.append(part.replace("_", " ").replace("p999", "p99.9"))
    name = ", ".join(words)
    where = GROUPS.get(group, group.replace("_", " "))
    return f"{where}: {name}" if where else name

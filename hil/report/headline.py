"""The report's first lines, in words and numbers: (1) were the limits of (2) held, and by what
margin (each peak as a share of its limit)? (2) The command age D against D* (the certificate)
and the margin. (3) The stalls closest to D*: when, how long, why (top 3). (4) The share of
plant samples that never got a command. Every number is one already in the report: the peaks
of summary.json (every plant step) and the trace, the certificate (for a run: hil.measure's),
the timing object.
"""

from __future__ import annotations

from typing import Any

from hil.verdict import UNITS

#: Each signal of (2) and its limit's symbol (its unit is hil.verdict's).
LIMITS = {"v": "φ1", "omega": "φ2", "tau1": "ϖ1", "tau2": "ϖ2"}
SYMBOL = {"v": "v", "omega": "ω", "tau1": "τ1", "tau2": "τ2"}
TOP_STALLS = 3


def ms(seconds: float) -> str:
    return f"{seconds * 1e3:.3f} ms"


def _limits(data: dict[str, Any], summary: dict[str, Any]) -> tuple[dict[str, Any], str]:
    cons = data["metrics"]["constraints"]
    violations = summary.get("violations") or {}
    out: dict[str, Any] = {"held": data["verdict"]["limits"] == "held"}
    parts = []
    broken = []
    for key, name in LIMITS.items():
        unit = UNITS[key]
        c = cons[key]
        n = violations.get(key)
        n = int(n) if isinstance(n, int | float) and not isinstance(n, bool) else None
        pct = 100.0 * c["ratio"]
        out[key] = {"max": c["peak"], "limit": c["limit"], "percent_of_limit": pct, "violations": n}
        sym = SYMBOL[key]
        limit = f"{name} = {c['limit']:.4g} {unit}"
        parts.append(f"max |{sym}| = {c['peak']:.4g} {unit} is {pct:.1f} % of {limit}")
        if (n or 0) > 0:
            broken.append(f"|{sym}| beyond {name} at {n} plant steps")
        elif not c["held"]:
            broken.append(f"|{sym}| beyond {name}")
    every = "over every plant step" if violations else "over the trace's samples"
    state = "held" if not broken else "BROKEN (" + "; ".join(broken) + ")"
    text = f"Limits of (2) {state}, {every}: " + "; ".join(parts) + "."
    return out, text


def _command_age(data: dict[str, Any]) -> tuple[dict[str, Any], str]:
    cert = data["certificate"]
    d, ds, margin = cert.get("d_max_s"), cert.get("d_star_s"), cert.get("margin_s")
    path = cert.get("path")
    out = {k: cert.get(k) for k in ("path", "d_max_s", "d_star_s", "margin_s", "held", "source")}
    if data["kind"] != "run" or path is None:
        what = f"Command age D ≤ Ts + worst delay = {ms(d)} (the scenario's timing)"
    elif d is None:
        return out, f"Command age: no command ever landed on the {path} path (D unknown)."
    else:
        what = f"Command age D = {ms(d)} on the applied path ({path})"
    if ds is None:
        return out, f"{what}; no certificate ({data['scenario']['law']} has none)."
    if cert.get("held"):
        state = "certificate held"
    elif d is not None and d > ds:
        state = "certificate NOT held (D > D*)"
    else:
        failed = ", ".join(cert.get("failed_conditions") or []) or "design conditions"
        state = f"certificate NOT held ({failed})"
    return out, f"{what} against D* = {ms(ds)}: margin {ms(margin)}, {state}."


def _stalls(data: dict[str, Any]) -> tuple[dict[str, Any], str]:
    cert = data["certificate"]
    stalls = list(cert.get("stalls") or [])
    thr = cert.get("stall_threshold_s")
    top = [{k: s.get(k) for k in ("t_s", "age_s", "cause", "owner")} for s in stalls[:TOP_STALLS]]
    total = cert.get("stall_count", len(stalls))
    stalled = cert.get("stalled_time_s")
    out = {"threshold_s": thr, "listed": len(stalls), "count": total, "top": top}
    out["stalled_time_s"] = stalled
    if data["kind"] != "run" or cert.get("path") is None:
        return out, "Stalls: not measured in a simulation (every command lands after its delay)."
    if thr is None:
        return out, "Stalls: no stall threshold without a certificate."
    rule = "max(3 Ts, D*/2)" if cert.get("d_star_s") is not None else "3 Ts"
    if not stalls:
        return out, (
            f"Stalls: none; the command age never exceeded the stall threshold {rule} = {ms(thr)}."
        )
    items = "; ".join(
        f"t = {s['t_s']:.3f} s, age {ms(s['age_s'])}, cause {s['cause']}"
        + (f" ({s['owner']})" if s.get("owner") else "")
        for s in top
    )
    spent = f", {ms(stalled)} in all above it" if stalled is not None else ""
    # A law without a certificate has no D*: its threshold is 3 Ts and the list is the longest.
    which = "closest to D*" if cert.get("d_star_s") is not None else "longest (no D* for this law)"
    return out, f"Stalls {which} (top {len(top)} of {total} above {ms(thr)}{spent}): {items}."


def _samples(data: dict[str, Any], summary: dict[str, Any]) -> tuple[dict[str, Any], str]:
    timing = (data.get("timing") or {}).get("summary") or {}
    n, judged = timing.get("samples_without_command"), timing.get("samples_judged")
    rate = timing.get("samples_without_command_rate")
    if data["kind"] == "run" and isinstance(n, int) and isinstance(rate, int | float):
        return (
            {"count": n, "judged": judged, "rate": rate},
            f"Samples without a command: {n} of {judged} ({100.0 * rate:.3f} %).",
        )
    if data["kind"] == "run":
        return {"count": None, "judged": None, "rate": None}, (
            "Samples without a command: not measured (the run has no such figure)."
        )
    dropped = summary.get("commands_dropped")
    extra = f"; {dropped} commands overtaken by a newer one and dropped" if dropped else ""
    return {"count": 0, "judged": None, "rate": 0.0}, (
        f"Samples without a command: none in a simulation (every sample's command lands{extra})."
    )


def headline(data: dict[str, Any], summary: dict[str, Any]) -> dict[str, Any]:
    """The four answers and the verdict, as data and as the report's first lines."""
    answers = {
        "limits": _limits(data, summary),
        "command_age": _command_age(data),
        "stalls": _stalls(data),
        "samples_without_command": _samples(data, summary),
    }
    v = data["verdict"]
    verdict = v.get("outcome", "PASS" if v["ok"] else "FAIL")
    v_text = (
        f"Verdict: {verdict}." if v["ok"] else f"Verdict: {verdict}: {'; '.join(v['reasons'])}."
    )
    if v.get("notes"):
        v_text += " " + " ".join(v["notes"])
    lines = [{"key": k, "text": text} for k, (_, text) in answers.items()]
    return {
        "verdict": verdict,
        **{k: facts for k, (facts, _) in answers.items()},
        "lines": [*lines, {"key": "verdict", "text": v_text}],
    }

"""How much timing a design can take: the sampled-data certificate (``hil margin``: the margin).

``hil certify SCENARIO.toml --ts S --delay S [--json]``: the sampled-data certificate. Checks
Assumption 2, (9), (11), (12) and the bound of docs/sampled_data_bound.md for the scenario's
unified law, says whether (2) is guaranteed at that period and worst delay and, if not,
proposes the nearest admissible parameters. Exit 0 held, 1 not held, 2 bad input. Defaults:
--ts = [timing] ts, --delay = [timing] delay + the jitter's bound (uniform: jitter; normal: 4
standard deviations, as the report does).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Annotated, Any, NotRequired, TypedDict

import typer

from hil import options
from hil.bundled import resolve_scenario
from hil.commands import ForceOpt, app
from hil.errors import BadInputError, NegativeVerdictError
from hil.ticker import start_line

if TYPE_CHECKING:
    from hil.folder.jsonio import JsonObject
    from hil.provenance import Toml


class EmpiricalBreak(TypedDict):
    """Where (2) really broke under the worst disturbance found (``--empirical``;
    hil.analysis.margin.conservatism), certificate.json's ``empirical``."""

    age_at_break_s: float | None  # None: no break up to 1024 x the age
    k_star: float | None
    first_broken: str | None
    disturbance: str | None
    loops: int
    ratio_to_d_star: float | None  # the break over D* (docs/sampled_data_bound.md, section 10)


class CertifyFacts(TypedDict):
    """What certificate.json and ``--json`` hold besides the certificate and the proposal."""

    scenario: str
    law: str  # unified or unified_boundary
    params: dict[str, float]  # the law's gains as resolved ('auto' resolved)
    auto_notes: list[str]
    d_star_s: float  # the largest command age the bound allows
    empirical: NotRequired[EmpiricalBreak]


def _params(table: Toml, context: Any) -> tuple[SimpleNamespace, bool, list[str]]:
    """The unified law's gains (Table 1 where not given, 'auto' resolved), whether it has the
    boundary layer, and the resolution's notes. The scenario's reader has checked every key
    and number of the table (controller_service.registry.check_table). The eta re-arm keeps eta
    in [0, 1] and z1, z2 in [-m, m], all the bound uses (docs/laws.md): the same certificate."""
    from controller_service.design import DesignError, resolve_auto
    from controller_service.registry import EPS_DEFAULT, TABLE1
    from hil.law.facts import Law

    law = Law.of(table)
    if not law.has_certificate:
        raise BadInputError(
            f"[controller] law = {law.name!r}: the certificate covers the unified laws only"
        )
    boundary = law.boundary_layer
    values: Toml = {**TABLE1, **(EPS_DEFAULT if boundary else {})}
    values.update({k: v for k, v in table.items() if k in values})
    try:
        resolved = resolve_auto(values, context)
    except DesignError as exc:
        raise NegativeVerdictError(f"certificate not held: {exc}") from exc
    return SimpleNamespace(**resolved.params), boundary, list(resolved.notes)


def _table(cert: Any, law: str) -> Any:
    from rich.table import Table

    age = f"delay = {cert.delay:g} s (age D = {cert.age:g} s)"
    table = Table(title=f"{law}: certificate at ts = {cert.ts:g} s, {age}")
    for column in ("condition", "value", "bound", "margin", "held"):
        table.add_column(column, justify="left" if column == "condition" else "right")
    for c in cert.conditions:
        mark = "info" if c.kind == "info" else ("yes" if c.held else "NO")
        if c.kind == "info" and not c.held:
            mark = "info: no"
        table.add_row(c.name, f"{c.value:.6g}", f"{c.bound:.6g}", f"{c.margin:.4g}", mark)
    return table


def _conservatism_lines(facts: CertifyFacts) -> list[str]:
    lines = [f"D* = {1e3 * facts['d_star_s']:.3f} ms: the largest command age the bound allows."]
    emp = facts.get("empirical")
    if emp is None:
        return lines
    if emp["age_at_break_s"] is None:
        lines.append("Empirical break: none found up to 1024 x this age (worst disturbance).")
        return lines
    lines.append(
        f"Empirical break under the worst disturbance found: command age "
        f"{1e3 * emp['age_at_break_s']:.1f} ms ({emp['first_broken']} first; "
        f"{emp['disturbance']}; {emp['loops']} loops)."
    )
    if emp["ratio_to_d_star"] is not None:
        lines.append(
            f"Ratio empirical break / D* = {emp['ratio_to_d_star']:.2f} "
            "(docs/sampled_data_bound.md, section 10)."
        )
    return lines


def certify_scenario(
    path: str, ts: float | None, delay: float | None, empirical: bool = False
) -> tuple[Any, Any, CertifyFacts]:
    """(certificate, proposal or None, facts) for a scenario file; BadInputError on bad input.
    The facts hold D* and, ``empirical``, the break under the worst disturbance found and its
    ratio to D*."""
    from controller_service.certificate import CertificateError, certify, critical_age, propose
    from hil.scenario import (
        DELAY_MAX,
        TS_MAX,
        TS_MIN,
        build_reference,
        design_context,
        load_scenario,
    )

    ts = options.optional_number("--ts", ts, TS_MIN, TS_MAX)
    delay = options.optional_number("--delay", delay, 0.0, DELAY_MAX)
    scenario = load_scenario(resolve_scenario(path))
    context = design_context(scenario, build_reference(scenario))
    params, boundary, notes = _params(dict(scenario.controller), context)
    ts_used = scenario.timing.ts if ts is None else ts
    t = scenario.timing  # the worst delay: the jitter's bound is 4 sigma when it is normal
    spread = 4.0 * t.jitter if t.jitter_kind == "normal" else t.jitter
    delay_used = float(t.delay + spread) if delay is None else delay
    loop = (params, context, ts_used, delay_used, boundary)
    start = {"v0": scenario.initial.v, "w0": scenario.initial.omega}
    try:
        cert = certify(*loop, **start, watchdog_timeout=scenario.realtime.command_timeout)
        proposal = None if cert.held else propose(*loop, **start)
    except CertificateError as exc:
        raise BadInputError(str(exc)) from exc
    facts: CertifyFacts = {
        "scenario": str(path),
        "law": "unified_boundary" if boundary else "unified",
        "params": dict(vars(params)),
        "auto_notes": notes,
        "d_star_s": critical_age(params, context, boundary, **start),
    }
    if empirical:  # the break under the worst disturbance found (hil.analysis.margin.conservatism)
        from hil.analysis.margin import record as margin_record
        from hil.analysis.margin.conservatism import empirical_break

        rec = empirical_break(scenario, ts_used, delay_used)
        fault = margin_record.law_fault_sentence(rec)
        if fault is not None:  # the law failed in the search: no empirical break to give
            raise NegativeVerdictError(str(fault))
        facts["empirical"] = {
            "age_at_break_s": rec.age_at_break_s,
            "k_star": rec.k_star,
            "first_broken": rec.first_broken,
            "disturbance": rec.disturbance_at_break,
            "loops": rec.loops,
            "ratio_to_d_star": rec.conservatism,
        }
    return cert, proposal, facts


#: hil certify --out's file: what --json prints.
CERTIFICATE_JSON = "certificate.json"


def _document(cert: Any, proposal: Any, facts: CertifyFacts) -> JsonObject:
    """The certificate as --json prints it and --out writes it."""
    doc = {**facts, "certificate": cert.to_dict()}
    if proposal is not None:
        doc["proposal"] = {
            "params": None if proposal.params is None else dict(vars(proposal.params)),
            "reason": proposal.reason,
            "changes": {k: list(v) for k, v in proposal.changes.items()},
        }
    return doc


@app.command("certify")
def certify_command(
    scenario: str = typer.Argument(
        ..., help="Scenario TOML file or a bundled scenario's name (hil scenarios)."
    ),
    ts: float = typer.Option(
        None,
        help="Longest gap between sample times of "
        "successive applied commands, s (default: [timing] ts).",
    ),
    delay: float = typer.Option(
        None, help="Worst sample-to-apply latency, s (default: [timing] delay + jitter bound)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the certificate as JSON."),
    empirical: bool = typer.Option(
        False,
        "--empirical",
        help="Also search where (2) really breaks under the worst disturbance (batch "
        "simulation, hil.margin; seconds to minutes) and print its ratio to D*.",
    ),
    out: Annotated[
        Path | None,
        typer.Option(help=f"Also write the certificate ({CERTIFICATE_JSON}) in this folder."),
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Is (2) guaranteed for the sampled, delayed loop? (docs/sampled_data_bound.md)"""
    from hil.folder import claim

    claim.check("--out", out, force)
    if empirical:  # the long part: a search in simulation
        what = f"{scenario}, the certificate and the break under the worst disturbance"
        start_line("certify", what, "seconds to minutes", out or "the terminal only")
    cert, proposal, facts = certify_scenario(scenario, ts, delay, empirical)
    doc = _document(cert, proposal, facts)
    if out is not None:
        path = claim.take(out, "certify") / CERTIFICATE_JSON
        path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
    else:
        from rich.console import Console

        console = Console()
        console.print(_table(cert, facts["law"]))
        console.print(
            f"|v| <= {cert.v_bound:.6g} (phi1 = {cert.phi1:g}), "
            f"|w| <= {cert.w_bound:.6g} (phi2 = {cert.phi2:g})"
        )
        for note in [*facts["auto_notes"], *cert.notes]:
            console.print(f"- {note}")
        verdict = "GUARANTEED" if cert.held else "NOT guaranteed"
        console.print(f"(2) is {verdict} at this period and worst delay.")
        for line in _conservatism_lines(facts):
            console.print(line)
        if proposal is not None:
            if proposal.params is None:
                console.print(f"No admissible design: {proposal.reason}")
            else:
                changes = ", ".join(
                    f"{k} {a:.6g} -> {b:.6g}" for k, (a, b) in proposal.changes.items()
                )
                console.print(f"Nearest admissible design: {changes}")
    if not cert.held:
        raise NegativeVerdictError(
            "certificate not held: " + ", ".join(c.name for c in cert.failed())
        )

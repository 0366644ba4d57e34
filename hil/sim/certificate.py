"""The sampled-data certificate at a given period and delay, for a simulation or a sweep
(a run's certificate is measured: :func:`hil.analysis.measure.figures.measure`).

Uses :func:`controller_service.certificate.certify` (docs/sampled_data_bound.md). Only the
unified laws (10) and (19) have a certificate.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

from controller_service.certificate import certify, critical_age
from hil.folder.records import Certificate
from hil.folder.scenario_view import ScenarioView
from hil.law.facts import Law


@dataclass(frozen=True)
class CertificateFigures:
    ts: float
    delay: float
    v_bound: float | None
    w_bound: float | None
    held: bool | None  # None: the law has no certificate
    source: str
    detail: dict[str, Any]  # controller_service.certificate's figures, or the error


def certificate(sv: ScenarioView, ts: float, delay: float) -> CertificateFigures:
    if not Law(sv.law).has_certificate:
        return CertificateFigures(ts, delay, None, None, None, "none (not a unified law)", {})
    source = "controller_service.certificate"
    params = SimpleNamespace(**sv.controller)
    try:
        cert = certify(params, sv.context, ts, delay, sv.boundary_layer, v0=sv.v0, w0=sv.w0)
    except Exception as exc:  # a design the certificate rejects is a figure, not a crash
        return CertificateFigures(ts, delay, None, None, False, source, {"error": str(exc)})
    detail = {**cert.to_dict(), "failed": [c.name for c in cert.failed()]}
    v, w = float(cert.v_bound), float(cert.w_bound)
    return CertificateFigures(ts, delay, v, w, bool(cert.held), source, detail)


#: The keys of a certificate object (docs/run-folder.md, "certificate").
CONTRACT_KEYS = ("path", "d_max_s", "d_star_s", "margin_s", "held", "v_bound", "omega_bound",
                 "stall_threshold_s", "stalls")  # fmt: skip


def no_certificate(path: str | None, d_max: float | None, source: str) -> Certificate:
    """A certificate object with D alone (a law without the bound, or before it is known)."""
    out = dict.fromkeys(CONTRACT_KEYS)
    out.update(path=path, d_max_s=d_max, stalls=[], source=source, failed_conditions=[])
    return out


def scenario_certificate(sv: ScenarioView) -> Certificate:
    """A simulation's certificate in the contract's shape: D is the scenario's longest possible
    command age, Ts + the worst delay (delay plus the jitter's bound), an upper bound of the
    simulated ages; D* and the bounds as hil.analysis.measure computes them for a run."""
    d = sv.ts + sv.worst_delay
    out = no_certificate(
        None, d, "scenario: D = Ts + worst delay (an upper bound of the simulated ages)"
    )
    if not Law(sv.law).has_certificate:
        out["source"] = "none (not a unified law)"
        return out
    params = SimpleNamespace(**sv.controller)
    try:
        d_star = critical_age(params, sv.context, sv.boundary_layer, v0=sv.v0, w0=sv.w0)
    except Exception as exc:  # a design the certificate rejects is a figure, not a crash
        out.update(held=False, error=str(exc))
        return out
    c = certificate(sv, d, 0.0)
    out["failed_conditions"] = list(c.detail.get("failed", []))
    out.update(d_star_s=d_star, margin_s=d_star - d, held=bool(c.held) and d <= d_star)
    out.update(v_bound=c.v_bound, omega_bound=c.w_bound)
    out["stall_threshold_s"] = max(3 * sv.ts, 0.5 * d_star)
    if c.held is False and "error" in c.detail:
        out["error"] = c.detail["error"]
    return out

"""The sampled-data certificate at a given period and delay, for a report or a sweep.

Uses ``controller_service.certificate.certify`` (the certificate engineer's module) when it is
installed; otherwise the bound as DESIGN.md states it (:func:`hil.analysis.design_note_bounds`),
marked as such in ``source``. Only the unified laws (10) and (19) have a certificate.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

from hil.analysis import design_note_bounds
from hil.report.scenario_view import UNIFIED_LAWS, ScenarioView


@dataclass(frozen=True)
class CertificateFigures:
    ts: float
    delay: float
    v_bound: float | None
    w_bound: float | None
    held: bool | None  # None: the law has no certificate
    source: str
    detail: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        return {
            "ts": self.ts,
            "delay": self.delay,
            "v_bound": self.v_bound,
            "w_bound": self.w_bound,
            "held": self.held,
            "source": self.source,
            "detail": self.detail,
        }


def _float(value: Any, default: float) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return default


def certificate(sv: ScenarioView, ts: float, delay: float) -> CertificateFigures:
    if sv.law not in UNIFIED_LAWS:
        return CertificateFigures(ts, delay, None, None, None, "none (not a unified law)", {})
    try:
        from controller_service.certificate import certify
    except ImportError:
        certify = None
    if certify is not None:
        try:
            cert = certify(
                SimpleNamespace(**sv.controller),
                sv.context,
                ts,
                delay,
                sv.boundary_layer,
                v0=sv.v0,
                w0=sv.w0,
            )
        except Exception as exc:  # a design the certificate rejects is a figure, not a crash
            return CertificateFigures(
                ts, delay, None, None, False, "controller_service.certificate", {"error": str(exc)}
            )
        detail = cert.to_dict() if hasattr(cert, "to_dict") else {}
        failed = getattr(cert, "failed", None)
        if callable(failed):
            detail["failed"] = [c.name for c in failed()]
        return CertificateFigures(
            ts,
            delay,
            float(cert.v_bound),
            float(cert.w_bound),
            bool(cert.held),
            "controller_service.certificate",
            detail,
        )
    ctx, lim, c = sv.context, sv.limits, sv.controller
    c1 = ctx.mu1 + lim.phi1 + 1.0
    c2 = c1 + ctx.mu1**2 + ctx.mu2**2
    v_bound, w_bound = design_note_bounds(
        mu1=ctx.mu1,
        mu2=ctx.mu2,
        m1=_float(c.get("m1"), 0.5),
        m2=_float(c.get("m2"), 0.5),
        lam=_float(c.get("lam"), 1.0),
        rho=_float(c.get("rho"), 1.0),
        c2=c2,
        varpi1=lim.varpi1,
        varpi2=lim.varpi2,
        s1=ctx.s1,
        s2=ctx.s2,
        ts=ts,
        delay=delay,
    )
    held = v_bound <= lim.phi1 and w_bound <= lim.phi2
    return CertificateFigures(
        ts, delay, v_bound, w_bound, held, "DESIGN.md bound (certificate module absent)", {}
    )

"""The sampled-data certificate at a given period and delay, for a report or a sweep.

Uses :func:`controller_service.certificate.certify` (docs/sampled_data_bound.md). Only the
unified laws (10) and (19) have a certificate.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

from controller_service.certificate import certify
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


def certificate(sv: ScenarioView, ts: float, delay: float) -> CertificateFigures:
    if sv.law not in UNIFIED_LAWS:
        return CertificateFigures(ts, delay, None, None, None, "none (not a unified law)", {})
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

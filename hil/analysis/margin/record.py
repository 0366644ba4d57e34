"""``margin.json``: the result of ``hil margin``, written into the run (or output) folder, read
back by the report. One typed record, written by the folder's JSON policy (non-finite numbers
as null, atomic); unknown keys are ignored on reading so that a newer writer does not break an
older reader."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from controller_service.laws.guard import LawFault
from hil.errors import BadInputError
from hil.folder import layout
from hil.folder.jsonio import read_json_object, write_json
from hil.folder.records import LawFaultRecord
from protocol.versions import MARGIN_SCHEMA_VERSION


@dataclass(frozen=True)
class MarginProbe:
    """One scale tried: k, the worst score (> 1: a limit broke), which limit, the pattern of
    the worst disturbance (None: the scenario's own), and D of the replayed timing at k."""

    k: float
    score: float
    limit: str
    broke: bool
    age_s: float
    disturbance: str | None = None


@dataclass(frozen=True)
class MarginRecord:
    """The timing margin k* (docs/margin.md): limits hold up to ``k_held`` x the replayed
    timing and break at ``k_star``; None when they held up to the largest k tried."""

    source: str
    law: str
    disturbance: str  # "scenario" (its own) or "worst" (searched)
    seeds: int
    duration_s: float
    k_star: float | None
    k_held: float | None
    first_broken: str | None
    disturbance_at_break: str | None
    d_measured_s: float | None
    d_replay_s: float
    age_at_break_s: float | None
    d_star_s: float | None
    error_bound_m: float | None = None
    loops: int = 0
    elapsed_s: float = 0.0
    probes: tuple[MarginProbe, ...] = field(default_factory=tuple)
    # the law failed in a loop (controller_service.laws.guard.LawFault.to_dict()): no k*
    law_fault: LawFaultRecord | None = None
    schema_version: int = MARGIN_SCHEMA_VERSION

    @property
    def conservatism(self) -> float | None:
        """The empirical break age over D*: how far the certificate is from a real break."""
        if self.age_at_break_s is None or not self.d_star_s:
            return None
        return self.age_at_break_s / self.d_star_s

    def to_dict(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "conservatism": self.conservatism}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> MarginRecord:
        names = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in data.items() if k in names}
        probe_names = {f.name for f in dataclasses.fields(MarginProbe)}
        values["probes"] = tuple(
            MarginProbe(**{k: v for k, v in p.items() if k in probe_names})
            for p in data.get("probes", ())
        )
        return cls(**values)


def write(folder: Path, record: MarginRecord) -> Path:
    """margin.json in ``folder``, whole or not at all (:mod:`hil.folder.jsonio`)."""
    return write_json(folder / layout.MARGIN, record.to_dict())


def read(folder: Path | str | None) -> MarginRecord | None:
    """The folder's margin record, None when there is none or it cannot be read."""
    if folder is None or not (Path(folder) / layout.MARGIN).is_file():
        return None
    try:
        return MarginRecord.from_dict(read_json_object(Path(folder) / layout.MARGIN))
    except (BadInputError, TypeError, ValueError):
        return None


def law_fault_sentence(record: MarginRecord) -> str | None:
    """The sentence of the law's fault in the record's loops (None: the law never failed)."""
    if record.law_fault is None:
        return None
    return LawFault.from_dict(record.law_fault).sentence(layout.MARGIN)


def summary_lines(record: MarginRecord) -> list[str]:
    """What a report says about the margin, in a few lines."""
    what = "the worst disturbance found" if record.disturbance == "worst" else "its disturbance"
    if record.law_fault is not None:
        return [f"FAIL: no timing margin, {law_fault_sentence(record)}."]
    if record.k_held is None:
        head = (
            f"Timing margin (hil margin, {what}): {record.first_broken} breaks even at "
            f"k = {record.k_star:.3g} x the measured timing (the smallest scale tried)."
        )
    elif record.k_star is None:
        head = (
            f"Timing margin (hil margin, {what}): the limits held up to "
            f"{record.k_held:g} x the measured timing (the largest scale tried)."
        )
    else:
        head = (
            f"Timing margin k* = {record.k_star:.3g} (hil margin, {what}): the limits hold up "
            f"to {record.k_held:.3g} x the measured timing; first broken: "
            f"{record.first_broken} at k = {record.k_star:.3g} (command age "
            f"{1e3 * (record.age_at_break_s or 0.0):.1f} ms)."
        )
    lines = [head]
    if record.disturbance_at_break:
        lines.append(f"Disturbance that broke it: {record.disturbance_at_break}.")
    if record.d_star_s and record.conservatism is not None:
        lines.append(
            f"D* = {1e3 * record.d_star_s:.2f} ms, empirical break under {what} "
            f"{1e3 * (record.age_at_break_s or 0.0):.1f} ms: ratio {record.conservatism:.2f} "
            "(docs/sampled_data_bound.md, section 10)."
        )
    return lines

"""The constraints (2) as figures: a measured peak against its limit and the sampled-data bound,
judged with summary.json's tolerance. Below both wings: the verdict (:mod:`hil.verdict`), the
analysis's metrics (:mod:`hil.analysis.trace_metrics`) and the sweep judge with the same."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import TypedDict


@dataclass(frozen=True)
class Limit:
    """One limit of the constraints (2): the signal it bounds (``key``, as in the trace), its
    [limits] key, the paper's symbol for it, the signal's symbol and unit (model (1)'s inputs
    tau1, tau2 are normalized: accelerations)."""

    key: str
    name: str
    symbol: str
    signal: str
    unit: str

    @property
    def peak_key(self) -> str:
        """summary.json's key of the signal's peak over every plant step."""
        return f"max_abs_{self.key}"


#: The four limits of (2), in the order every page lists them.
LIMITS = (
    Limit("v", "phi1", "φ1", "v", "m/s"),
    Limit("omega", "phi2", "φ2", "ω", "rad/s"),
    Limit("tau1", "varpi1", "ϖ1", "τ1", "m/s²"),
    Limit("tau2", "varpi2", "ϖ2", "τ2", "rad/s²"),
)
LIMIT_NAMES = {lim.key: lim.name for lim in LIMITS}  # signal -> [limits] key
PEAK_KEYS = {lim.key: lim.peak_key for lim in LIMITS}  # signal -> summary.json's peak key
UNITS = {lim.key: lim.unit for lim in LIMITS}
SYMBOLS = {lim.key: lim.symbol for lim in LIMITS}  # signal -> the limit's symbol
SIGNALS = {lim.key: lim.signal for lim in LIMITS}  # signal -> its symbol

# The ASCII spellings (the [limits] keys, the trace's columns) and their paper symbols, longest
# first so that "varpi1" is never read as "pi1"; "w" is the certificate's name for ω.
_ASCII = sorted(
    [(lim.name, lim.symbol) for lim in LIMITS]
    + [(lim.key, lim.signal) for lim in LIMITS if lim.key != lim.signal]
    + [("w", "ω")],
    key=lambda kv: -len(kv[0]),
)
_WORD = re.compile(
    r"(?<![A-Za-z0-9_.])(" + "|".join(re.escape(k) for k, _ in _ASCII) + r")(?![A-Za-z0-9_])"
)


def in_symbols(text: str) -> str:
    """``text`` with the limits' ASCII names as the paper's symbols (phi2 -> φ2, |omega| ->
    |ω|, tau1 -> τ1), the one symbol style of every page; only whole words, and "w" only between
    bars (|w|), so keys such as ``max_abs_tau1`` or words such as "w~" are left alone."""
    table = dict(_ASCII)

    def sub(m: re.Match[str]) -> str:
        word = m.group(1)
        if word == "w":
            before, after = m.string[m.start() - 1 : m.start()], m.string[m.end() : m.end() + 1]
            return "ω" if before == "|" and after == "|" else word
        return table[word]

    return _WORD.sub(sub, text)


# summary.json's tolerance: a violation is beyond 1e-9 relative (docs/design.md, section 3).
LIMIT_REL_TOL = 1e-9


class Constraint(TypedDict, total=False):
    """One constraint of (2) judged (:meth:`ConstraintFigure.as_dict`)."""

    name: str
    peak: float
    limit: float
    ratio: float
    held: bool
    bound: float | None
    within_bound: bool | None


@dataclass(frozen=True)
class ConstraintFigure:
    """One constraint of (2): the measured peak against its limit and (velocities) the
    sampled-data bound of docs/sampled_data_bound.md / the certificate."""

    name: str
    peak: float
    limit: float
    bound: float | None

    @property
    def ratio(self) -> float:
        """peak / limit: above 1 the constraint (2) is broken (overshoot = ratio - 1)."""
        return self.peak / self.limit if self.limit > 0 else math.inf

    @property
    def held(self) -> bool:
        return self.peak <= self.limit * (1.0 + LIMIT_REL_TOL)

    @property
    def within_bound(self) -> bool | None:
        return None if self.bound is None else self.peak <= self.bound * (1.0 + LIMIT_REL_TOL)

    def as_dict(self) -> Constraint:
        return Constraint(
            name=self.name,
            peak=self.peak,
            limit=self.limit,
            ratio=self.ratio,
            held=self.held,
            bound=self.bound,
            within_bound=self.within_bound,
        )

"""Where in its period the periodic controller ticks, after the plant's sample.

A periodic controller serves sample k at its tick if the sample's State has arrived by then
(else the tick serves k - 1 and sample k gets no command), and its command counts as on time if
it lands within the period (tick + compute + the command's hop < Ts after the sample). So a tick
at phase p after the sample serves every sample when

    arrival < p < Ts - (compute + command hop),

which some p satisfies only if the loop's own time (arrival + compute + hop) is under Ts.

- ``"half"`` (the default): p = Ts/2 from the first tick, as the bench always did.
- ``"auto"``: the first :data:`WARM_STATES` fresh States and computes are watched at Ts/2;
  then p is set once to the middle of the window between the q-quantile (:data:`QUANTILE`) of
  the arrival (plant sample -> State received) and Ts minus the q-quantiles of the compute and
  of the State's hop (plant send -> received; the command's hop is taken as equal: the same
  transport and size), kept within [Ts/8, 7 Ts/8]. When the window is shut (the loop's own
  time at the quantile is a period or more) p is still its middle, and the choice says so.
  Arrivals need the plant's and the controller's clocks to agree (one host): a median arrival
  outside [0, 4 Ts] means they do not, and the phase stays Ts/2 (said in the choice).

The choice goes into the controller's hop log (``tick_phase*`` meta) and from there into the
run's summary (hil.measure).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

WARM_STATES = 2000  # fresh States watched before the phase is chosen (1 s at 2 kHz)
QUANTILE = 0.99
EDGE = 8  # the phase stays within [Ts/EDGE, Ts - Ts/EDGE]
UNRELATED = 4  # an arrival beyond this many periods (or negative): the clocks differ


@dataclass(frozen=True)
class PhaseChoice:
    """The tick's phase after the sample and what it was chosen from (ns)."""

    phase_ns: int
    arrival_q_ns: int  # the arrival's quantile (sample -> State received)
    path_q_ns: int  # compute + hop quantiles: what the command still needs after the tick
    window_open: bool  # arrival_q + path_q < Ts: a phase serves (nearly) every sample
    clocks_related: bool = True

    def as_meta(self) -> dict[str, Any]:
        return {f"tick_phase_{k}": v for k, v in asdict(self).items()}


def choose_phase(
    period_ns: int, arrivals: Any, hops: Any, computes: Any, q: float = QUANTILE
) -> PhaseChoice:
    """The middle of the window (module doc) from observed arrivals, hops and computes."""
    arrivals = np.asarray(arrivals, dtype=np.int64)
    typical = float(np.median(arrivals)) if arrivals.size else -1.0
    if not 0 <= typical <= UNRELATED * period_ns:
        return PhaseChoice(period_ns // 2, -1, -1, False, clocks_related=False)
    a = int(np.quantile(arrivals, q))
    path = int(np.quantile(np.asarray(computes, np.int64), q)) + int(
        np.quantile(np.asarray(hops, np.int64), q)
    )
    lo, hi = period_ns // EDGE, period_ns - period_ns // EDGE
    phase = min(hi, max(lo, (a + period_ns - path) // 2))
    return PhaseChoice(int(phase), a, path, a + path < period_ns)


class PhaseLearner:
    """Collects what :func:`choose_phase` needs; :meth:`choice` gives it once, when enough
    was seen. ``state`` runs on the subscriber's thread, the rest on the control thread."""

    def __init__(self, period_ns: int, warm: int = WARM_STATES) -> None:
        self.period_ns = int(period_ns)
        self.warm = int(warm)
        self._arrivals = np.zeros(self.warm, np.int64)
        self._hops = np.zeros(self.warm, np.int64)
        self._computes = np.zeros(self.warm, np.int64)
        self._states = 0
        self._compute_count = 0
        self.done = False

    def state(self, arrival_ns: int, hop_ns: int) -> None:
        i = self._states
        if i < self.warm:
            self._arrivals[i], self._hops[i] = arrival_ns, hop_ns
            self._states = i + 1

    def compute(self, ns: int) -> None:
        i = self._compute_count
        if i < self.warm:
            self._computes[i] = ns
            self._compute_count = i + 1

    def choice(self) -> PhaseChoice | None:
        """The phase, once (then None), as soon as ``warm`` States and computes were seen."""
        if self.done or self._states < self.warm or self._compute_count < self.warm:
            return None
        self.done = True
        return choose_phase(self.period_ns, self._arrivals, self._hops, self._computes)

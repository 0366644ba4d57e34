"""Baseline [19]: the separate saturated stabilizer and tracker of Jiang, Lefeber & Nijmeijer
2001 ("Saturated stabilization and tracking of a nonholonomic mobile robot", Systems & Control
Letters 42), switched to the stabilizer when the reference stops.

The paper (Li et al. 2024, Section 4) uses eps = (1.6, 4, 1) for stabilization and
lam = (4.5, 0.4, 1.1) for tracking and shows the jolt of v at the switch (its Figure 19).

Form used. The original text could not be retrieved (searches found only citations). Both laws
below are bounded ("saturated") Lyapunov designs built from normalised terms, with the
parameter roles read off the paper's values: eps1 = 1.6 = phi1 bounds |v|, eps2 + eps3 = 5 <
phi2 = 5.1 bounds |w|; the tracker's bounds are |v| <= mu1 + lam2 and
|w| <= mu2 + lam1 + lam3 mu1 / 2 (4.975 at the paper's values). Errors are (4), theta_e wrapped.

Tracker (vd, wd not both zero), with N = 1 + xe^2 + ye^2:

    v_c = vd cos theta_e - lam2 xe / sqrt(N)
    w_c = wd - lam3 vd ye / N - lam1 sin theta_e
    V = ln(N)/2 + (1 - cos theta_e)/lam3,  V' = -lam2 xe^2/N^(3/2) - (lam1/lam3) sin^2 theta_e.

Stabilizer (vd = wd = 0; a time-varying law, since no continuous static one exists), with
rho2 = xe^2 + ye^2 and the heading excitation h = eps3 tanh(rho2) sin t:

    v_c = -eps1 xe / sqrt(N)
    w_c = eps3 tanh(rho2) cos t - eps2 (theta_e - h) / sqrt(1 + (theta_e - h)^2)

(v_c drives xe to zero while the heading oscillates about the target heading with an
amplitude that fades with the distance, so the lateral error is pushed out on average.)

The switch. [19] is two separate designs, so something outside them must decide when the task
changes; the paper switches "at 70 s", when the reference is told to stop. ``switch_time`` (s,
law time) is that supervisor's schedule: from then on the stabilizer acts, towards the reference's
pose (which, for circle_then_stop, decelerates over its short ramp and rests). Without
``switch_time`` the switch is the instant vd = wd = 0 exactly, which on a continuous-pose stop
comes after the ramp, when the tracker has already brought v to zero and nothing jumps.

Both commands go through the inner velocity loop of :mod:`controller_service.laws.jiang1997`
(feed-forward backward difference plus kv, kw = 20 1/s, torques clipped to +-varpi). At the
switch the commands jump, so the feed-forward difference saturates the torque for one sample:
that is the jolt the comparison is about, not an artefact to hide.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from controller_service.laws.base import DesignContext, ReferenceSample, RobotState
from controller_service.laws.jiang1997 import (
    INNER_K_DEFAULT,
    VelocityLoopController,
    positive_number,
    tracking_errors,
)

STAB_EPS_DEFAULT = (1.6, 4.0, 1.0)
TRACK_LAM_DEFAULT = (4.5, 0.4, 1.1)


def _triple(key: str, value: Any) -> tuple[float, float, float]:
    if isinstance(value, str) or not isinstance(value, Sequence) or len(value) != 3:
        raise ValueError(f"[controller.jiang2001] {key} must be a list of 3 numbers, got {value!r}")
    return tuple(positive_number("jiang2001", f"{key}[{i}]", v) for i, v in enumerate(value))  # type: ignore[return-value]


class Jiang2001Controller(VelocityLoopController):
    """[19]'s tracker and stabilizer, switched on vd = wd = 0; ``name = "jiang2001"``.

    Built as ``Jiang2001Controller(params, context)`` with params stab_eps = [e1, e2, e3],
    track_lam = [l1, l2, l3] and optional switch_time, inner_kv, inner_kw (the
    [controller.jiang2001] table).
    Telemetry ``mode`` is 1 while stabilizing, 0 while tracking.
    """

    name = "jiang2001"
    KEYS = ("stab_eps", "track_lam", "switch_time", "inner_kv", "inner_kw")

    def __init__(self, params: Mapping[str, Any], context: DesignContext) -> None:
        unknown = sorted(set(params) - set(self.KEYS))
        if unknown:
            raise ValueError(f"[controller.jiang2001]: unknown key(s) {', '.join(unknown)}")
        self.stab_eps = _triple("stab_eps", params.get("stab_eps", STAB_EPS_DEFAULT))
        self.track_lam = _triple("track_lam", params.get("track_lam", TRACK_LAM_DEFAULT))
        switch = params.get("switch_time")
        self.switch_time = (
            None if switch is None else positive_number("jiang2001", "switch_time", switch)
        )
        super().__init__(
            context,
            positive_number("jiang2001", "inner_kv", params.get("inner_kv", INNER_K_DEFAULT)),
            positive_number("jiang2001", "inner_kw", params.get("inner_kw", INNER_K_DEFAULT)),
        )

    def kinematic(self, ns: Any, t: Any, state: RobotState, ref: ReferenceSample) -> tuple:
        xe, ye, the = tracking_errors(ns, state, ref)
        vd, wd = ref.vd, ref.wd
        rho2 = xe * xe + ye * ye
        n = 1.0 + rho2
        sqrt_n = ns.sqrt(n)
        lam1, lam2, lam3 = self.track_lam
        v_track = vd * ns.cos(the) - lam2 * xe / sqrt_n
        w_track = wd - lam3 * vd * ye / n - lam1 * ns.sin(the)
        eps1, eps2, eps3 = self.stab_eps
        fade = ns.tanh(rho2)
        heading_error = the - eps3 * fade * ns.sin(t)
        v_stab = -eps1 * xe / sqrt_n
        w_stab = eps3 * fade * ns.cos(t) - eps2 * heading_error / ns.sqrt(
            1.0 + heading_error * heading_error
        )
        if ns.is_array:
            stopped = (vd == 0.0) & (wd == 0.0)
            if self.switch_time is not None:
                stopped = stopped | (t >= self.switch_time)
        else:
            stopped = (vd == 0.0 and wd == 0.0) or (
                self.switch_time is not None and t >= self.switch_time
            )
        v_c = ns.where(stopped, v_stab, v_track)
        w_c = ns.where(stopped, w_stab, w_track)
        mode = ns.where(stopped, 1.0, 0.0)
        return v_c, w_c, mode, xe, ye, the

    def resolved_table(self) -> dict[str, Any]:
        return {
            "law": self.name,
            "jiang2001": {
                "stab_eps": list(self.stab_eps),
                "track_lam": list(self.track_lam),
                **({} if self.switch_time is None else {"switch_time": self.switch_time}),
                "inner_kv": self.inner_kv,
                "inner_kw": self.inner_kw,
            },
        }

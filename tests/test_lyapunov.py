"""The Lyapunov argument of Theorem 1 on the reduced closed loop (16) with (8).

On the sliding manifold (v = alpha_v, w = alpha_w) docs/design.md (section 1) gives
    V' = ye vd sin(xi)/r - z1^2/m1 - 2 z2^2/(lam m2),
so V(t) minus the integral of |vd sin xi| never increases (|ye/r| < 1).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller_service.laws.base import ReferenceSample, RobotState
from controller_service.laws.unified import (
    UnifiedMemory,
    UnifiedParams,
    lyapunov_v,
    unified_signals,
)
from runtime.mathns import FLOAT_MATH as NS

PARAMS = UnifiedParams()

# Extended state X = (t, x, y, theta, xd, yd, thetad, eta, z1, z2); vd, wd given per case.


def signals(X, vd, wd, v=0.0):
    t, x, y, th, xd, yd, thd, eta, z1, z2 = X
    memory = UnifiedMemory(eta, z1, z2)
    ref = ReferenceSample(xd, yd, thd, vd, wd)
    sig = unified_signals(NS, t, RobotState(x, y, th, v, 0.0), ref, memory, PARAMS.lam, PARAMS.rho)
    return sig, memory


def V(X, vd, wd):
    sig, memory = signals(X, vd, wd)
    return lyapunov_v(sig, memory, PARAMS, NS)


def reduced_rhs(X, vd, wd):
    """(16) with (8) and the virtual robot (3): v = alpha_v (which does not depend on v), then
    w = alpha_w evaluated with that v (alpha_w depends on v through g = r')."""
    alpha_v = signals(X, vd, wd)[0].alpha_v
    sig, _ = signals(X, vd, wd, v=alpha_v)
    _, _, _, th, _, _, thd, eta, z1, z2 = X
    return np.array(
        [
            1.0,
            alpha_v * math.cos(th),
            alpha_v * math.sin(th),
            sig.alpha_w,
            vd * math.cos(thd),
            vd * math.sin(thd),
            wd,
            -(vd * vd + wd * wd) * eta,
            PARAMS.l1 / 2 * (sig.xe / sig.r - z1 / PARAMS.m1),
            PARAMS.l2 / 2 * (math.sin((sig.theta_e - sig.xi) / 2) - z2 / PARAMS.m2),
        ]
    ), sig


def formula(X, vd, sig):
    z1, z2 = X[8], X[9]
    return (
        sig.ye * vd * math.sin(sig.xi) / sig.r
        - z1 * z1 / PARAMS.m1
        - 2.0 * z2 * z2 / (PARAMS.lam * PARAMS.m2)
    )


def test_v_dot_matches_the_formula_at_random_states():
    rng = np.random.default_rng(2024)
    for _ in range(200):
        X = np.array(
            [
                rng.uniform(0, 50),
                *rng.uniform(-3, 3, 2),
                rng.uniform(-6, 6),
                *rng.uniform(-3, 3, 2),
                rng.uniform(-6, 6),
                rng.uniform(0, 1),
                rng.uniform(-0.5, 0.5),
                rng.uniform(-0.5, 0.5),
            ]
        )
        vd, wd = rng.uniform(-0.5, 0.5), rng.uniform(-0.2, 0.2)
        F, sig = reduced_rhs(X, vd, wd)
        h = 1e-5
        # The chain rule as a central difference along the flow: grad V . F.
        numeric = (V(X + h * F, vd, wd) - V(X - h * F, vd, wd)) / (2 * h)
        expected = formula(X, vd, sig)
        assert numeric == pytest.approx(expected, abs=1e-7, rel=1e-6)


def test_a_sign_error_in_the_law_would_be_caught():
    """The check is not vacuous: flipping lam's term in alpha_w breaks the identity."""
    global PARAMS
    X = np.array([1.3, 0.7, -1.1, 0.4, 0.0, 0.2, -0.3, 0.9, 0.1, -0.2])
    _, sig = reduced_rhs(X, 0.5, 0.2)
    saved = PARAMS
    try:
        PARAMS = UnifiedParams(lam=-1.0)
        F_bad, _ = reduced_rhs(X, 0.5, 0.2)
    finally:
        PARAMS = saved
    h = 1e-5
    numeric_bad = (V(X + h * F_bad, 0.5, 0.2) - V(X - h * F_bad, 0.5, 0.2)) / (2 * h)
    assert abs(numeric_bad - formula(X, 0.5, sig)) > 1e-3


def rk4_run(X0, vd, wd, duration, h=1e-3):
    """RK4 on (X, I) with I' = |vd sin xi|; returns V - I at every step."""

    def rhs(Y):
        F, sig = reduced_rhs(Y[:-1], vd, wd)
        return np.append(F, abs(vd * math.sin(sig.xi)))

    Y = np.append(np.array(X0, dtype=float), 0.0)
    out = [V(Y[:-1], vd, wd) - Y[-1]]
    for _ in range(round(duration / h)):
        k1 = rhs(Y)
        k2 = rhs(Y + 0.5 * h * k1)
        k3 = rhs(Y + 0.5 * h * k2)
        k4 = rhs(Y + h * k3)
        Y = Y + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(V(Y[:-1], vd, wd) - Y[-1])
    return np.array(out), Y


@pytest.mark.slow
@pytest.mark.parametrize(
    ("vd", "wd", "X0", "min_drop"),
    [
        # The paper's circle, from 1 m lateral error with a heading error and nonzero z.
        (0.5, 0.2, [0.0, 0.0, -1.0, 0.5, 0.0, 0.0, 0.0, 1.0, 0.3, -0.2], 0.1),
        # Stabilization (a point reference): a lateral error, the hard case.
        (0.0, 0.0, [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0], 0.03),
    ],
    ids=["circle", "stop"],
)
def test_v_minus_integral_never_increases_on_the_reduced_loop(vd, wd, X0, min_drop):
    W, _ = rk4_run(X0, vd, wd, duration=12.0)
    increases = np.diff(W)
    assert increases.max() <= 1e-10
    # ... and the run is not trivial: V decreased (slowly at rest, as docs/design.md says).
    assert W[-1] < W[0] - min_drop

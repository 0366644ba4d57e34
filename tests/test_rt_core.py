"""The pure cores of the real-time pair: deadlines without drift, guarded torques, lazy plant."""

from __future__ import annotations

import math

import pytest

from controller_service.laws.base import ControlOutput, Limits, ReferenceSample, RobotState
from controller_service.laws.guard import LawFaultError
from controller_service.service import ControlCore
from plant_emulator.disturbances import Disturbance
from plant_emulator.dynamics import Extremes, PlantState, rk4_float
from plant_emulator.service import DelayInjector, PlantCore
from runtime.realtime import DeadlineClock, Tick


class _Fixed:
    name = "fixed"

    def __init__(self, tau1: float, tau2: float) -> None:
        self.tau = (tau1, tau2)

    def initial_memory(self, n=None, z1=0.0, z2=0.0):
        return 0

    def update(self, t, dt, state, ref, memory):
        return ControlOutput(self.tau[0], self.tau[1], {}), memory + 1


class _Ref:
    def sample(self, t):
        return ReferenceSample(0.0, 0.0, 0.0, 0.0, 0.0)


S0 = RobotState(0.0, 0.0, 0.0, 0.0, 0.0)


def test_control_core_never_emits_a_torque_outside_the_limits():
    core = ControlCore(_Fixed(99.0, -999.0), _Ref(), 0.001, Limits())
    t1, t2, _ = core.step(0.0, S0)
    assert (t1, t2) == (3.3, -51.0)
    assert core.rejections.get("clamped_tau1") == 1
    assert core.memory == 1  # memory advanced once per sample


@pytest.mark.parametrize(
    ("tau", "detail"),
    [((float("nan"), 1.0), "tau1 = nan"), ((1.0, float("inf")), "tau2 = inf")],
)
def test_control_core_stops_at_a_non_finite_torque_as_a_fault_of_the_law(tau, detail):
    """A non-finite torque is the law's fault (controller_service.laws.guard), raised with its
    time and input, never a zero torque sent on as if nothing happened; the memory keeps."""
    core = ControlCore(_Fixed(*tau), _Ref(), 0.001, Limits())
    state = RobotState(0.5, -0.25, 0.125, 1.0, 0.0625)
    with pytest.raises(LawFaultError) as err:
        core.step(1.5, state)
    f = err.value.fault
    assert (f.kind, f.detail, f.t_s, f.law) == ("non_finite", detail, 1.5, "fixed")
    assert f.state == {"x": 0.5, "y": -0.25, "theta": 0.125, "v": 1.0, "omega": 0.0625}
    assert core.memory == 0
    # The last line stays: a non-finite value reaching the guard still never leaves it.
    assert core.guard(*tau) in ((0.0, 1.0), (1.0, 0.0))


def test_deadline_clock_has_no_drift_and_counts_skipped_slots(monkeypatch):
    import runtime.realtime as rt

    wakes = iter([100, 1_000_050, 2_000_010, 5_500_000, 6_000_001])
    monkeypatch.setattr(rt, "wait_until_ns", lambda deadline, spin: next(wakes))
    clock = DeadlineClock(1_000_000, 0)
    ticks = [clock.next() for _ in range(5)]
    # Deadlines stay on the grid start + k * period whatever the lateness ...
    assert [t.deadline_ns for t in ticks[:3]] == [0, 1_000_000, 2_000_000]
    # ... a wake-up past its successor's deadline is a miss, reported against the deadline of
    # the slot it was due for (3 ms), never re-based (2.5 ms late, as cyclictest would say);
    # the two slots whose deadlines passed meanwhile (4 and 5 ms) are skipped, counted.
    assert ticks[3] == Tick(3, 3_000_000, 5_500_000, 2)
    assert ticks[3].lateness_ns == 2_500_000
    assert ticks[4].k == 6 and ticks[4].deadline_ns == 6_000_000
    assert clock.misses == 1 and clock.skipped == 2


def test_deadline_clock_reports_a_long_stall_in_full(monkeypatch):
    """A wake-up 11.7 ms after its deadline at 2 ms reads 11.7 ms, five slots skipped."""
    import runtime.realtime as rt

    wakes = iter([10, 2_000_020, 4_000_000 + 11_700_000, 16_000_005])
    monkeypatch.setattr(rt, "wait_until_ns", lambda deadline, spin: next(wakes))
    clock = DeadlineClock(2_000_000, 0)
    ticks = [clock.next() for _ in range(4)]
    assert ticks[2].lateness_ns == 11_700_000
    assert ticks[2].skipped == 5  # slots 3..7 (deadlines 6..14 ms) passed during the stall
    assert ticks[3].k == 8 and ticks[3].deadline_ns == 16_000_000
    assert clock.misses == 1 and clock.skipped == 5


def test_lazy_plant_equals_one_integration_over_the_same_steps():
    lim = Limits()
    dist = Disturbance(kind="sine", amplitude1=0.1, amplitude2=0.2, freq=1.0)
    s0 = PlantState(0.0, 0.0, 0.1, 0.2, 0.0)
    core = PlantCore(s0, h=1e-4, limits=lim, disturbance=dist)
    core.hold(1.0, -2.0)
    for t in (2e-4, 5e-4, 1e-3):  # events at step boundaries
        core.advance_to(t)
    ref = rk4_float(s0, 1.0, -2.0, 0.0, 1e-4, 10, dist, 0.0, None, lim, Extremes())
    for a, b in zip(core.state, ref, strict=True):
        assert a == pytest.approx(b, abs=1e-12)
    assert core.extremes.steps == 10


def test_plant_core_clamps_held_commands_to_the_limits():
    core = PlantCore(PlantState(0, 0, 0, 0, 0), h=1e-3, limits=Limits())
    core.hold(1e9, float("nan"))
    assert (core.cmd1, core.cmd2) == (3.3, 0.0)


def test_delay_injector_is_seeded_and_bounded():
    a = DelayInjector(0.002, 0.001, "uniform", 3)
    b = DelayInjector(0.002, 0.001, "uniform", 3)
    xs = [a.extra_ns() for _ in range(200)]
    assert xs == [b.extra_ns() for _ in range(200)]
    assert all(2_000_000 <= x <= 3_000_000 for x in xs)
    assert not math.isclose(min(xs), max(xs))

"""The law and the test ``hil new-law NAME`` writes into the user's folder.

The template is a working law, not a stub: it tracks the paper's circle within the limits (2),
runs on floats and on numpy arrays from one source, and its test proves both (the tests of this
repository run the written test in a fresh process, tests/test_new_law.py).
"""

from __future__ import annotations

import importlib.util
import keyword
import re
from pathlib import Path
from string import Template

from hil.errors import BadInputError

_NAME = re.compile(r"[a-z_][a-z0-9_]*")

LAW = Template('''\
"""$cls: a tracking law for the hil bench, written by `hil new-law $name`; edit freely.

Run it (from this folder; hil finds $name.py here or next to the scenario):
    hil sim paper_tracking --law $name:$cls --out runs/$name
    hil sweep paper_tracking --law $name:$cls --out runs/$name-sweep
    hil run paper_tracking --law $name:$cls
Test it:
    python test_$name.py      (with pytest installed: python -m pytest test_$name.py)

The bench builds it as $cls(params, context): params is the scenario's [controller] table
without `law` (your gains), context the design context (the limits (2) and the disturbance and
reference bounds). At every control sample it calls update(t, dt, state, ref, memory) and
applies the returned torques until the next sample. update is pure: what the law remembers
lives in `memory`, which update takes and returns.

One source, two forms: `hil run` and `hil sim` pass floats (one robot); `hil sweep` passes
numpy arrays of shape (N,) (N robots at once). `namespace_for` picks math or numpy once per
call: use only its functions on state values (no `if x > 0`, `max()`, `float()`).

The law: kinematic tracking (Kanayama et al. 1990) turns the pose error, seen from the robot,
into wanted velocities v_c, w_c (kept within phi1, phi2); a proportional-integral velocity loop
turns them into torques (model (1): v' = tau1, omega' = tau2), clipped to varpi1, varpi2.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from controller_service.laws.base import ControlOutput, DesignContext, ReferenceSample, RobotState
from runtime.mathns import namespace_for

# Gains, overridden by the scenario's [controller] table: pose (kx, ky, kth), velocity loop
# (kv, kw, 1/s) and its integral (ki, 1/s^2).
DEFAULTS = {"kx": 1.0, "ky": 4.0, "kth": 2.0, "kv": 5.0, "kw": 5.0, "ki": 1.0}
TELEMETRY = ("ex", "ey", "eth", "v_c", "w_c", "nonfinite")


class Memory(NamedTuple):
    """What the law remembers between samples: the integrals of the velocity errors."""

    iv: Any
    iw: Any


class $cls:
    """Kinematic tracking + PI velocity loop, within the limits (2)."""

    name = "$name"

    def __init__(self, params: dict[str, Any], context: DesignContext) -> None:
        unknown = sorted(set(params) - set(DEFAULTS))
        if unknown:
            raise ValueError(f"unknown key(s) {', '.join(unknown)}; known: {', '.join(DEFAULTS)}")
        gains = {**DEFAULTS, **params}
        for key, value in gains.items():
            if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
                raise ValueError(f"{key} must be a number >= 0, got {value!r}")
        self.kx, self.ky, self.kth, self.kv, self.kw, self.ki = (float(gains[k]) for k in DEFAULTS)
        self.limits = context.limits

    def initial_memory(self, n: int | None = None, z1: float = 0.0, z2: float = 0.0) -> Memory:
        # z1, z2 start the unified law's adaptive states (8); this law has none.
        if n is None:
            return Memory(0.0, 0.0)
        return Memory(np.zeros(n), np.zeros(n))

    def update(
        self, t: Any, dt: float, state: RobotState, ref: ReferenceSample, memory: Memory
    ) -> tuple[ControlOutput, Memory]:
        xp = namespace_for(state.x, state.v, ref.xd, memory.iv)
        lim = self.limits
        # A sum is finite only when every term is: one test for all inputs.
        ok = xp.isfinite(sum(state) + sum(ref) + memory.iv + memory.iw)
        if not xp.is_array and not ok:  # one robot, bad input: no torque, memory kept
            telemetry = {**dict.fromkeys(TELEMETRY, 0.0), "nonfinite": 1.0}
            return ControlOutput(0.0, 0.0, telemetry), memory
        kept = memory
        if xp.is_array:  # robots with a bad input compute on zeros, then get zero torque
            state = RobotState(*(xp.where(ok, f, 0.0) for f in state))
            ref = ReferenceSample(*(xp.where(ok, f, 0.0) for f in ref))
            memory = Memory(xp.where(ok, memory.iv, 0.0), xp.where(ok, memory.iw, 0.0))
        c, s = xp.cos(state.theta), xp.sin(state.theta)
        dx, dy = ref.xd - state.x, ref.yd - state.y
        ex = c * dx + s * dy  # ahead of the robot
        ey = -s * dx + c * dy  # to its left
        eth = xp.atan2(xp.sin(ref.thetad - state.theta), xp.cos(ref.thetad - state.theta))
        v_c = xp.clip(ref.vd * xp.cos(eth) + self.kx * ex, -lim.phi1, lim.phi1)
        w_c = xp.clip(
            ref.wd + ref.vd * (self.ky * ey + self.kth * xp.sin(eth)), -lim.phi2, lim.phi2
        )
        ev, ew = v_c - state.v, w_c - state.omega
        tau1 = xp.clip(ref.dvd + self.kv * ev + self.ki * memory.iv, -lim.varpi1, lim.varpi1)
        tau2 = xp.clip(ref.dwd + self.kw * ew + self.ki * memory.iw, -lim.varpi2, lim.varpi2)
        # Memory at t + dt: one Euler step of the integrals, each bounded so that its term alone
        # cannot ask for more than the torque limit (no wind-up while clipped).
        b1 = lim.varpi1 / self.ki if self.ki > 0 else 0.0
        b2 = lim.varpi2 / self.ki if self.ki > 0 else 0.0
        new = Memory(xp.clip(memory.iv + ev * dt, -b1, b1), xp.clip(memory.iw + ew * dt, -b2, b2))
        bad = xp.where(ok, 0.0, 1.0)
        if xp.is_array:
            tau1, tau2 = xp.where(ok, tau1, 0.0), xp.where(ok, tau2, 0.0)
            new = Memory(xp.where(ok, new.iv, kept.iv), xp.where(ok, new.iw, kept.iw))
        telemetry = {"ex": ex, "ey": ey, "eth": eth, "v_c": v_c, "w_c": w_c, "nonfinite": bad}
        return ControlOutput(tau1, tau2, telemetry), new
''')

TEST = Template('''\
"""Tests of $name.py: run with `python test_$name.py` or `python -m pytest test_$name.py`."""

from __future__ import annotations

import math

import numpy as np

from controller_service.laws.base import DesignContext, ReferenceSample, RobotState
from $name import $cls

CONTEXT = DesignContext()  # the paper's limits (2)


def _robots(n: int, seed: int = 1) -> tuple[RobotState, ReferenceSample]:
    rng = np.random.default_rng(seed)
    state = RobotState(*(rng.uniform(-2.0, 2.0, n) for _ in range(5)))
    ref = ReferenceSample(*(rng.uniform(-1.0, 1.0, n) for _ in range(7)))
    return state, ref


def test_floats_and_arrays_give_the_same_torques_and_memory():
    """hil sweep runs the law on arrays, hil run on floats: both must be the same law."""
    law = $cls({}, CONTEXT)
    n, dt = 50, 0.002
    state, ref = _robots(n)
    memory = law.initial_memory(n)
    for k in range(3):  # a few samples, so the memory is compared after it has moved
        out, memory_next = law.update(k * dt, dt, state, ref, memory)
        for i in range(n):
            one = law.initial_memory(None)._make(float(f[i]) for f in memory)
            out_i, next_i = law.update(
                k * dt, dt, RobotState(*(float(f[i]) for f in state)),
                ReferenceSample(*(float(f[i]) for f in ref)), one,
            )
            assert math.isclose(out_i.tau1, out.tau1[i], rel_tol=1e-12, abs_tol=1e-12)
            assert math.isclose(out_i.tau2, out.tau2[i], rel_tol=1e-12, abs_tol=1e-12)
            for a, b in zip(next_i, memory_next, strict=True):
                assert math.isclose(a, b[i], rel_tol=1e-12, abs_tol=1e-12)
        memory = memory_next


def test_torques_stay_within_the_limits():
    law = $cls({"kx": 50.0, "kv": 100.0}, CONTEXT)  # gains that ask for far too much
    state, ref = _robots(200, seed=2)
    out, _ = law.update(0.0, 0.002, state, ref, law.initial_memory(200))
    assert np.all(np.abs(out.tau1) <= CONTEXT.limits.varpi1)
    assert np.all(np.abs(out.tau2) <= CONTEXT.limits.varpi2)


def test_a_bad_input_gives_no_torque_and_keeps_the_memory():
    law = $cls({}, CONTEXT)
    state = RobotState(math.nan, 0.0, 0.0, 0.0, 0.0)
    ref = ReferenceSample(0.0, 0.0, 0.0, 0.5, 0.2)
    memory = law.initial_memory(None)._replace(iv=0.3)
    out, after = law.update(0.0, 0.002, state, ref, memory)
    assert (out.tau1, out.tau2) == (0.0, 0.0) and after == memory


def test_it_tracks_the_papers_circle_within_the_limits():
    """The closed loop in the bench's own simulator (hil sim's code), 30 s at Ts = 10 ms."""
    from hil.bundled import resolve_scenario
    from hil.law.option import with_law
    from hil.scenario import load_scenario
    from hil.sim import simulate

    scenario = with_law(load_scenario(resolve_scenario("paper_tracking")), "$name:$cls")
    result = simulate(scenario.with_overrides(duration=30.0, ts=0.01))
    assert result.summary["limits_held"], result.summary["violations"]
    assert result.summary["final_position_error"] < 0.05


if __name__ == "__main__":
    for name, fn in list(globals().items()):
        if name.startswith("test_"):
            fn()
            print(f"ok  {name}")
''')


def class_name(name: str) -> str:
    """``my_law`` -> ``MyLaw``."""
    return "".join(part[:1].upper() + part[1:] for part in name.split("_") if part) or "Law"


def check_name(name: str, folder: Path = Path(".")) -> str:
    """A module name the bench can import from ``folder``, or BadInputError."""
    if not _NAME.fullmatch(name) or keyword.iskeyword(name):
        raise BadInputError(
            f"NAME {name!r}: use a Python module name (lower case letters, digits and _, "
            "not starting with a digit), e.g. my_law"
        )
    # Installed packages are looked up first: a law named like one would never be found. The
    # user's own file of that name (``python -m`` puts the working directory on the path) is
    # not one: overwriting it is --force's question.
    spec = importlib.util.find_spec(name)
    own = {folder.resolve(), Path.cwd().resolve()}
    if spec is not None and (spec.origin is None or Path(spec.origin).resolve().parent not in own):
        raise BadInputError(f"NAME {name!r}: a module of that name is installed; pick another")
    return name


def write_law(name: str, folder: Path, force: bool = False) -> list[Path]:
    """Write NAME.py and test_NAME.py into ``folder``; the paths written."""
    files = {folder / f"{name}.py": LAW, folder / f"test_{name}.py": TEST}
    existing = [str(p) for p in files if p.exists()]
    if existing and not force:
        raise BadInputError(f"{', '.join(existing)} already exist(s); --force overwrites")
    folder.mkdir(parents=True, exist_ok=True)
    for path, text in files.items():
        path.write_text(text.substitute(name=name, cls=class_name(name)))
    return list(files)

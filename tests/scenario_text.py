"""Scenario text shared by tests and benchmarks: the paper's circle, started off it; each user
adds the tables it varies ([controller], [disturbance], [timing], [run], [sweep])."""

from __future__ import annotations

from typing import Any

#: The paper's circle (vd = 0.5 m/s, wd = 0.2 rad/s).
CIRCLE = {"kind": "circle", "vd": 0.5, "wd": 0.2}
#: 1.4 m off the circle, heading along x (the Table 1 runs).
FAR = {"x": -1.0, "y": 1.0, "theta": 0.0}
#: 0.6 m off, turned 0.5 rad away (the margin and adversary set-ups).
NEAR = {"x": -1.0, "y": -0.6, "theta": 0.5}
#: The paper's Table 1 gains.
TABLE1 = {"law": "unified", "m1": 0.5, "m2": 0.5, "l1": 0.5, "l2": 0.5, "lam": 1.0, "rho": 1.0}


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)


def toml_text(**tables: dict[str, Any] | None) -> str:
    """TOML of flat tables (None: left out), in the order given."""
    out = []
    for name, table in tables.items():
        if table is None:
            continue
        out.append(f"[{name}]")
        out += [f"{k} = {_value(v)}" for k, v in table.items()]
        out.append("")
    return "\n".join(out)


def circle(initial: dict[str, float] = FAR, **tables: dict[str, Any] | None) -> str:
    """The circle from ``initial``, then ``tables``."""
    return toml_text(reference=CIRCLE, initial=initial, **tables)


CIRCLE_TABLE1 = circle(controller=TABLE1)

#: A loop whose timing cannot honestly fail on a working machine (tests/test_clean_run.py):
#: 50 Hz control and sensing with torque limits low against the speed limits, so that the
#: certificate allows a command age D* = 498 ms (``hil certify``: 25 periods) while a working
#: loop's D is 1.5 periods and the host's scheduling. Tests of something else than the verdict
#: run it too, so that their verdict is known: PASS.
CLEAN_RATE_HZ = 50.0
CLEAN_D_STAR_S = 0.498
CLEAN_50HZ = circle(
    NEAR,
    limits={"phi1": 1.6, "phi2": 5.1, "varpi1": 1.0, "varpi2": 8.0},
    controller={**TABLE1, "l1": 0.3, "l2": 0.3, "lam": 0.5, "rho": 0.05},
    # Control and sensing at 1 / ts (``--rate`` moves both: sensor_rate is the control rate).
    timing={"ts": 1.0 / CLEAN_RATE_HZ},
    # The plant's watchdog (zero torque after command_timeout without a command) is outside
    # the certificate's assumptions below D*: 2 s keeps it out of a clean run's way.
    realtime={"command_timeout": 2.0},
)

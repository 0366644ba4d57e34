"""The columns every trace.csv starts with (docs/run-folder.md), shared by runs, simulations and
reports so the three cannot drift apart."""

from __future__ import annotations

#: Required by the contract, in this order: one row per control sample.
TRACE_COLUMNS: tuple[str, ...] = (
    "t",
    *("x", "y", "theta", "v", "omega"),  # the robot's pose (theta unwrapped) and velocities
    *("xd", "yd", "thetad"),  # the reference pose
    *("tau1", "tau2"),  # the torques applied
)
#: The commanded torques (before clamping where they are applied), right after.
COMMAND_COLUMNS: tuple[str, ...] = ("tau1_cmd", "tau2_cmd")

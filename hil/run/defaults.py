"""The scenario ``hil run`` uses with no arguments: the paper's tracking circle (Section 4),
a short run with both command paths live over loopback (no vcan, no root needed)."""

from __future__ import annotations

DEFAULT_DURATION = 10.0

# The paper gives its initial conditions only in figures; this one starts 0.5 m beside and
# 0.3 rad off the circle, at rest (DESIGN.md: "choose your own, state them").
PAPER_TRACKING_TOML = """\
# hil run's default: the paper's tracking circle (Li et al. 2024, Section 4, Table 1).
[limits]
phi1 = 1.6
phi2 = 5.1
varpi1 = 3.3
varpi2 = 51.0

[reference]
kind = "circle"
vd = 0.5
wd = 0.2
x0 = 0.0
y0 = 0.0
theta0 = 0.0

[initial]
x = 0.0
y = -0.5
theta = 0.3
v = 0.0
omega = 0.0

[controller]
law = "unified"
m1 = 0.5
m2 = 0.5
l1 = 0.5
l2 = 0.5
lam = 1.0
rho = 1.0

[timing]
ts = 0.002

[run]
duration = 10.0

[realtime]
rate = 500.0
sensor_rate = 500.0
trigger = "periodic"
state_timeout = 0.05
command_timeout = 0.05
scheduling = "fifo"

[can]
interface = "zenoh_can"
channel = "hil0"
bitrate = 1000000
node_left = 0
node_right = 1
"""

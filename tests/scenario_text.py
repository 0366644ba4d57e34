"""Scenario text shared by tests: the paper's circle with Table 1 gains, 1.4 m off the circle at
the start; each test appends the tables it varies ([timing], [run], [sweep])."""

CIRCLE_TABLE1 = """
[reference]
kind = "circle"
vd = 0.5
wd = 0.2

[initial]
x = -1.0
y = 1.0
theta = 0.0

[controller]
law = "unified"
m1 = 0.5
m2 = 0.5
l1 = 0.5
l2 = 0.5
lam = 1.0
rho = 1.0
"""

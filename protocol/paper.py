"""The paper's set-up (Li et al. 2024, Section 4), in one place: the limits (2) and the gains of
Table 1, the defaults of every scenario, law and command that does not give its own."""

from __future__ import annotations

from types import MappingProxyType

# The constraints (2): |v| <= phi1, |omega| <= phi2, |tau1| <= varpi1, |tau2| <= varpi2.
PAPER_LIMITS = MappingProxyType({"phi1": 1.6, "phi2": 5.1, "varpi1": 3.3, "varpi2": 51.0})
# Table 1: the adaptive laws' (8) m1, m2, l1, l2, (7)'s lam and the signal's rho.
TABLE1 = MappingProxyType({"m1": 0.5, "m2": 0.5, "l1": 0.5, "l2": 0.5, "lam": 1.0, "rho": 1.0})
# The boundary-layer widths of (19) in the paper's chattering-reduction run.
EPS_DEFAULT = MappingProxyType({"eps1": 0.1, "eps2": 0.1})

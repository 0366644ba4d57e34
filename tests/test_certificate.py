"""The sampled-data certificate (docs/sampled_data_bound.md): formulas against hand
computation at Table 1, verdicts, propose(), bad input, and the `hil certify` command."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import pytest

from controller_service.certificate import CertificateError, certify, critical_age, propose
from controller_service.design import lam_bound, rho_bound
from controller_service.laws.base import DesignContext, Limits
from controller_service.laws.unified import UnifiedParams
from hil.cli import main

PAPER = DesignContext()  # Section 4: phi1 1.6, phi2 5.1, varpi1 3.3, varpi2 51, mu 0.5/0.2, k 1
TABLE1 = UnifiedParams()


def test_table1_at_1ms_matches_hand_computation_and_holds():
    cert = certify(TABLE1, PAPER, 0.001, 0.0, boundary_layer=False)
    # V = mu1 + m1 + varpi1 D = 0.5 + 0.5 + 3.3e-3
    assert cert.v_bound == pytest.approx(1.0033, abs=1e-12)
    # c2s = (mu1 + V) + 1 + mu1^2 + mu2^2 = 1.5033 + 1 + 0.29
    assert cert.c2s == pytest.approx(2.7933, abs=1e-12)
    # W = mu2 + lam mu1 + m2 + rho c2s + varpi2 D = 0.2 + 0.5 + 0.5 + 2.7933 + 0.051
    assert cert.w_bound == pytest.approx(4.0443, abs=1e-12)
    assert cert.held and cert.constraints_guaranteed
    assert cert.margins["v"] == pytest.approx(1.6 - 1.0033)
    assert cert.condition("(11)").bound == pytest.approx(lam_bound(PAPER, m2=0.5, l2=0.5))
    assert cert.condition("(11)").bound == pytest.approx(5.96, abs=0.01)
    assert cert.condition("(12)").bound == pytest.approx(1.02, abs=0.01)


def test_disturbance_and_boundary_layer_terms():
    ctx = DesignContext(s1=0.3, s2=3.0)
    p = UnifiedParams(rho=0.5, eps1=0.1, eps2=0.2)
    sign = certify(p, ctx, 0.002, 0.003, boundary_layer=False)
    bl = certify(p, ctx, 0.002, 0.003, boundary_layer=True)
    assert sign.v_bound == pytest.approx(1.0 + (3.3 + 0.3) * 0.005)
    # (19): the push threshold eps1 s1 / varpi1 is added on the v side ...
    assert bl.v_bound - sign.v_bound == pytest.approx(0.1 * 0.3 / 3.3)
    # ... and eps2 s2 / varpi2 on the w side, plus rho times the c2s change from V.
    expected = 0.2 * 3.0 / 51.0 + 0.5 * (bl.v_bound - sign.v_bound)
    assert bl.w_bound - sign.w_bound == pytest.approx(expected)


def test_m1_near_limit_at_50ms_with_100ms_delay_is_not_held():
    p = UnifiedParams(m1=1.05)
    cert = certify(p, PAPER, 0.05, 0.1, boundary_layer=False)
    assert cert.condition("(9) m1").held  # the paper's design conditions all hold ...
    assert cert.condition("(12)").held
    assert cert.v_bound == pytest.approx(1.55 + 3.3 * 0.15)  # 2.045 > 1.6 ...
    assert not cert.condition("sampled |v|").held  # ... but sampling breaks the guarantee
    assert not cert.held and not cert.constraints_guaranteed
    # V > phi1: c0 must use V, not phi1 (caveat (b)).
    assert cert.c2s == pytest.approx(0.5 + cert.v_bound + 1.0 + 0.29)


def test_broken_paper_condition_fails_the_certificate_without_raising():
    cert = certify(UnifiedParams(rho=1.1), PAPER, 0.001, 0.0, boundary_layer=False)
    assert not cert.held
    assert [c.name for c in cert.failed()] == ["(12) rho < rho bound"]


@pytest.mark.parametrize("boundary", [False, True])
def test_propose_restores_the_certificate_with_the_largest_m1(boundary):
    ctx = DesignContext(s1=0.2, s2=2.0)
    p = UnifiedParams(m1=1.05, m2=0.8, eps1=0.1, eps2=0.1)
    ts, delay = 0.01, 0.01
    assert not certify(p, ctx, ts, delay, boundary).held
    proposal = propose(p, ctx, ts, delay, boundary)
    assert proposal.params is not None, proposal.reason
    assert certify(proposal.params, ctx, ts, delay, boundary).held
    new = proposal.params
    assert new.m1 < p.m1 and new.m2 <= p.m2 and new.lam <= p.lam and new.rho <= p.rho
    # m1 is the largest with V <= phi1: V sits exactly on phi1.
    assert proposal.certificate.v_bound == pytest.approx(ctx.limits.phi1)
    assert new.rho < rho_bound(ctx, m1=new.m1, m2=new.m2, l1=new.l1, l2=new.l2, lam=new.lam)


def test_propose_keeps_a_design_that_already_holds():
    proposal = propose(TABLE1, PAPER, 0.001, 0.0)
    assert proposal.params == TABLE1 and proposal.changes == {}


def test_propose_says_why_when_nothing_can_fix_it():
    proposal = propose(UnifiedParams(m1=1.05), PAPER, 0.05, 0.1)
    assert proposal.params is None
    assert "exceeds" in proposal.reason and "phi2" in proposal.reason
    proposal = propose(UnifiedParams(), PAPER, 0.2, 0.2)  # 3.3 x 0.4 > 1.6 - 0.5
    assert proposal.params is None and "phi1" in proposal.reason


def test_outage_tolerance():
    quiet = certify(TABLE1, PAPER, 0.001, 0.0, False, watchdog_timeout=0.002)
    assert quiet.outage_tolerance_s == math.inf  # no disturbance: zero torque cannot drift v
    noisy = certify(
        TABLE1, DesignContext(s1=0.1, s2=0.5), 0.001, 0.0, False, watchdog_timeout=0.002
    )
    assert 0.002 < noisy.outage_tolerance_s < math.inf


@pytest.mark.parametrize(
    ("ts", "delay", "params"),
    [
        (-0.001, 0.0, TABLE1),
        (math.nan, 0.0, TABLE1),
        (0.001, math.inf, TABLE1),
        (0.001, 0.0, UnifiedParams(m1=math.nan)),
        (0.001, 0.0, SimpleNamespace(m1=0.5)),
    ],
)
def test_bad_input_is_a_clear_rejection(ts, delay, params):
    with pytest.raises(CertificateError):
        certify(params, PAPER, ts, delay, boundary_layer=False)


def test_certificate_is_json_serializable():
    cert = certify(TABLE1, PAPER, 0.001, 0.0, False, watchdog_timeout=0.05)
    data = json.loads(json.dumps(cert.to_dict()))
    assert data["held"] is True and data["v_bound"] == pytest.approx(1.0033)


def _sampled_held(cert):
    return [c.held for c in cert.conditions if c.kind == "sampled"]


@pytest.mark.parametrize("boundary", [False, True])
def test_critical_age_at_table1_is_the_edge_of_the_certificate(boundary):
    ctx = DesignContext(s1=0.1, s2=1.0) if boundary else PAPER
    p = UnifiedParams(eps1=0.1, eps2=0.2) if boundary else TABLE1
    d_star = critical_age(p, ctx, boundary)
    assert 0.0 < d_star < math.inf
    assert _sampled_held(certify(p, ctx, d_star * (1 - 1e-6), 0.0, boundary)) == [True, True]
    assert not all(_sampled_held(certify(p, ctx, d_star * (1 + 1e-6), 0.0, boundary)))
    assert certify(p, ctx, d_star, 0.0, boundary).constraints_guaranteed
    if not boundary:
        # The w side binds (docs section 8): 1.2 + 1.79 + (1 + 3.3 D) + 51 D <= 5.1.
        assert d_star == pytest.approx(1.11 / 54.3, abs=1e-9)


@pytest.mark.parametrize(
    ("ctx", "v0"),
    [
        (DesignContext(limits=Limits(phi1=1.05)), 0.0),
        (DesignContext(limits=Limits(phi1=1.05), s1=0.3), 0.0),
        (DesignContext(limits=Limits(phi1=1.05), s1=0.3), -1.02),  # |v0| > mu1 + m1
    ],
)
def test_critical_age_known_answer_where_the_v_bound_binds(ctx, v0):
    d_star = critical_age(TABLE1, ctx, False, v0=v0)
    lim = ctx.limits
    expected = (lim.phi1 - max(abs(v0), ctx.mu1 + TABLE1.m1)) / (lim.varpi1 + ctx.s1)
    assert d_star == pytest.approx(expected, rel=1e-9)
    cert = certify(TABLE1, ctx, d_star, 0.0, False, v0=v0)
    assert cert.condition("sampled |w|").held  # the w side has room left at D*


def test_critical_age_boundary_layer_is_no_larger_than_sign_law():
    ctx = DesignContext(s1=0.3, s2=3.0)
    p = UnifiedParams(rho=0.5, eps1=0.1, eps2=0.2)
    sign, layer = critical_age(p, ctx, False), critical_age(p, ctx, True)
    assert 0.0 < layer <= sign
    assert layer < sign  # b1, b2 > 0 here: strictly smaller


@pytest.mark.parametrize(
    ("params", "ctx", "v0", "w0"),
    [
        (UnifiedParams(m1=1.2), PAPER, 0.0, 0.0),  # mu1 + m1 = 1.7 > phi1 at D = 0
        (TABLE1, PAPER, 1.7, 0.0),  # |v0| > phi1
        (TABLE1, PAPER, 0.0, 5.2),  # |w0| > phi2
        (TABLE1, DesignContext(s1=3.3), 0.0, 0.0),  # s1 = varpi1: the proof does not apply
    ],
)
def test_critical_age_is_zero_when_even_d_zero_breaks(params, ctx, v0, w0):
    assert critical_age(params, ctx, False, v0=v0, w0=w0) == 0.0


def test_critical_age_bad_input_is_a_clear_rejection():
    with pytest.raises(CertificateError):
        critical_age(UnifiedParams(m1=math.nan), PAPER, False)
    with pytest.raises(CertificateError):
        critical_age(TABLE1, PAPER, True)  # (19) needs eps1, eps2
    with pytest.raises(CertificateError):
        critical_age(TABLE1, PAPER, False, v0=math.inf)


SCENARIO = """
[reference]
kind = "circle"
vd = 0.5
wd = 0.2
k1 = 1.0
k2 = 1.0
[initial]
x = 0.0
y = -1.0
theta = 0.0
[controller]
law = "{law}"
m1 = {m1}
[timing]
ts = 0.05
delay = 0.08
jitter = 0.02
"""


def _write(tmp_path, law="unified", m1=0.5):
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.format(law=law, m1=m1))
    return str(path)


def test_cli_exit_codes_and_defaults(tmp_path, capsys):
    path = _write(tmp_path, m1=1.05)
    assert main(["certify", path, "--json"]) == 1  # defaults: ts 0.05, delay 0.08 + 0.02
    out = json.loads(capsys.readouterr().out)
    assert out["certificate"]["ts"] == 0.05 and out["certificate"]["delay"] == pytest.approx(0.1)
    assert out["certificate"]["held"] is False and out["proposal"]["params"] is None
    assert main(["certify", path, "--ts", "0.001", "--delay", "0"]) == 0
    assert "GUARANTEED" in capsys.readouterr().out
    assert main(["certify", path, "--ts", "0.01", "--delay", "0.01", "--json"]) == 1
    proposed = json.loads(capsys.readouterr().out)["proposal"]
    assert proposed["params"] is not None and proposed["changes"]["m1"][1] < 1.05


def test_cli_bad_input(tmp_path):
    assert main(["certify", str(tmp_path / "missing.toml")]) == 2
    assert main(["certify", _write(tmp_path), "--ts", "-1"]) == 2
    assert main(["certify", _write(tmp_path, law="jiang1997")]) == 2


@pytest.mark.parametrize("m1", ["nan", "inf", "-inf", '"x"', "true"])
def test_cli_refuses_a_bad_controller_value_with_a_clear_message(tmp_path, capsys, m1):
    """Certify must never certify a design it could not read: the [controller] value is refused."""
    assert main(["certify", _write(tmp_path, m1=m1), "--ts", "0.001", "--delay", "0"]) == 2
    captured = capsys.readouterr()
    assert "GUARANTEED" not in captured.out
    assert "m1" in captured.err, captured.err


def test_cli_refuses_an_unknown_controller_key(tmp_path, capsys):
    path = tmp_path / "s.toml"
    path.write_text(SCENARIO.format(law="unified", m1=0.5).replace("m1 = 0.5", "m1 = 0.5\nmx = 1"))
    assert main(["certify", str(path), "--ts", "0.001", "--delay", "0"]) == 2
    assert "mx" in capsys.readouterr().err


def test_positive_gains_are_shown_as_given_not_negated(tmp_path, capsys):
    """ "m1 > 0" reads value m1 (0.7 here), bound 0, margin 0.7: the table and the JSON both."""
    cert = certify(SimpleNamespace(**{**vars(TABLE1), "m1": 0.7}), PAPER, 0.001, 0.0, False)
    c = cert.condition("m1 > 0")
    assert (c.value, c.bound, c.margin, c.held) == (0.7, 0.0, 0.7, True)
    assert c.to_dict()["relation"] == ">" and cert.condition("(9) m1").to_dict()["relation"] == "<"
    bad = certify(SimpleNamespace(**{**vars(TABLE1), "rho": -0.2}), PAPER, 0.001, 0.0, False)
    r = bad.condition("rho > 0")
    assert (r.value, r.margin, r.held) == (-0.2, -0.2, False)
    path = _write(tmp_path, m1=0.7)
    main(["certify", path, "--ts", "0.001", "--delay", "0"])
    rows = [line for line in capsys.readouterr().out.splitlines() if "> 0" in line]
    m1_row = next(line for line in rows if "m1 > 0" in line)
    cells = [cell.strip() for cell in m1_row.split("│")[1:-1]]
    assert cells[1:4] == ["0.7", "0", "0.7"], m1_row
    assert not any("-0.5" in line or "-0.7" in line for line in rows), rows

"""References (3): closed forms match integration of (3), maxima bound the samples, csv rules."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from controller_service.references import (
    Circle,
    CircleThenStop,
    Lemniscate,
    Point,
    Reference,
    build_reference,
)


def integrate_virtual_robot(ref, t_end, h=1e-3):
    """RK4 of (3) driven by the reference's own vd(t), wd(t); returns the final pose."""
    s0 = ref.sample(0.0)
    pose = np.array([s0.xd, s0.yd, s0.thetad])

    def rhs(t, p):
        s = ref.sample(t)
        return np.array([s.vd * math.cos(p[2]), s.vd * math.sin(p[2]), s.wd])

    t = 0.0
    for _ in range(round(t_end / h)):
        k1 = rhs(t, pose)
        k2 = rhs(t + h / 2, pose + h / 2 * k1)
        k3 = rhs(t + h / 2, pose + h / 2 * k2)
        k4 = rhs(t + h, pose + h * k3)
        pose = pose + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        t += h
    return pose


def close_to_closed_form(ref, t_end, tol):
    pose = integrate_virtual_robot(ref, t_end)
    s = ref.sample(t_end)
    assert pose == pytest.approx([s.xd, s.yd, s.thetad], abs=tol)


def test_circle_closed_form_matches_integration():
    close_to_closed_form(Circle(0.5, 0.2, 1.0, -2.0, 0.7), 20.0, 1e-9)
    close_to_closed_form(Circle(0.4, 0.0, 1.0, 2.0, -0.3), 5.0, 1e-9)


def test_circle_then_stop_is_continuous_and_matches_integration():
    ref = CircleThenStop(0.5, 0.2, 0.0, 0.0, 0.0, stop_time=3.0, decel1=1.0, decel2=1.0)
    # Through the ramp (0.5 s: |vd|/k1 dominates) and into rest; the ramp kinks are inside
    # RK4 steps, so the tolerance is looser than for the circle.
    close_to_closed_form(ref, 5.0, 1e-6)
    assert ref.ramp == pytest.approx(0.5)
    before, after = ref.sample(3.0), ref.sample(3.0 + 1e-9)
    assert after.xd == pytest.approx(before.xd, abs=1e-8)
    assert after.thetad == pytest.approx(before.thetad, abs=1e-8)
    rest = ref.sample(100.0)
    assert (rest.vd, rest.wd, rest.dvd, rest.dwd) == (0.0, 0.0, 0.0, 0.0)
    assert ref.sample(4.0) == rest
    assert ref.rest_pose() == (rest.xd, rest.yd, rest.thetad)
    mid = ref.sample(3.25)
    assert mid.vd == pytest.approx(0.25) and mid.dvd == pytest.approx(-1.0)
    assert mid.wd == pytest.approx(0.1) and mid.dwd == pytest.approx(-0.4)
    assert (ref.mu1, ref.mu2, ref.k1, ref.k2) == pytest.approx((0.5, 0.2, 1.0, 0.4))


def test_circle_then_stop_straight_line_and_slow_deceleration():
    ref = CircleThenStop(-0.5, 0.0, 1.0, 1.0, 0.5, stop_time=1.0, decel1=0.25, decel2=1.0)
    close_to_closed_form(ref, 4.0, 1e-6)
    assert ref.k1 <= 0.25 + 1e-15


def test_lemniscate_matches_integration_and_flat_outputs():
    ref = Lemniscate(scale=2.0, period=20.0, x0=1.0, y0=-1.0)
    close_to_closed_form(ref, 20.0, 1e-8)
    # Flat outputs: the heading is the direction of the velocity, continuous over time.
    times = np.linspace(0, 40, 4001)
    headings = np.array([ref.sample(t).thetad for t in times])
    assert np.max(np.abs(np.diff(headings))) < 0.05
    for t in (0.3, 7.7, 13.1):
        h = 1e-6
        a, b = ref.sample(t - h), ref.sample(t + h)
        assert ref.sample(t).dvd == pytest.approx((b.vd - a.vd) / (2 * h), abs=1e-6)
        assert ref.sample(t).dwd == pytest.approx((b.wd - a.wd) / (2 * h), abs=1e-6)


@pytest.mark.parametrize(
    "ref",
    [
        Circle(),
        Point(1.0, 2.0, 3.0),
        CircleThenStop(stop_time=2.0),
        Lemniscate(scale=3.0, period=17.0),
    ],
    ids=["circle", "point", "circle_then_stop", "lemniscate"],
)
def test_reported_maxima_bound_the_samples(ref):
    assert isinstance(ref, Reference)
    rng = np.random.default_rng(5)
    for t in rng.uniform(0, 60, 5000):
        s = ref.sample(float(t))
        assert abs(s.vd) <= ref.mu1 and abs(s.wd) <= ref.mu2
        assert abs(s.dvd) <= ref.k1 and abs(s.dwd) <= ref.k2


def test_lemniscate_maxima_are_tight():
    ref = Lemniscate(scale=2.0, period=30.0)
    vd = [ref.sample(t).vd for t in np.linspace(0, 30, 3001)]
    assert max(vd) == pytest.approx(ref.mu1, rel=2e-3)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "ref.csv"
    path.write_text(text)
    return path


GOOD = "t,xd,yd,thetad,vd,wd\n0,0,0,0,0,0\n1,1,2,0.5,1,0.2\n3,2,2,0.5,0,0.2\n"


def test_csv_interpolates_and_holds(tmp_path):
    write(tmp_path, GOOD)
    ref = build_reference({"kind": "csv", "path": "ref.csv"}, tmp_path)
    s = ref.sample(0.5)
    assert (s.xd, s.yd, s.thetad, s.vd, s.wd) == pytest.approx((0.5, 1.0, 0.25, 0.5, 0.1))
    assert (s.dvd, s.dwd) == pytest.approx((1.0, 0.2))
    s = ref.sample(2.0)
    assert (s.xd, s.vd, s.dvd) == pytest.approx((1.5, 0.5, -0.5))
    end = ref.sample(10.0)
    assert (end.xd, end.yd, end.thetad, end.vd, end.wd) == (2.0, 2.0, 0.5, 0.0, 0.2)
    assert (end.dvd, end.dwd) == (0.0, 0.0)
    assert ref.sample(-1.0).xd == 0.0
    assert (ref.mu1, ref.mu2, ref.k1, ref.k2) == pytest.approx((1.0, 0.2, 1.0, 0.2))


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("t,xd,yd,thetad,vd,wd\n0,0,0,0,0,0\n1,1,x,0,0,0\n", ["row 3", "column yd"]),
        ("t,xd,yd,thetad,vd\n0,0,0,0,0\n", ["missing column", "wd"]),
        ("t,xd,yd,thetad,vd,wd\n0,0,0,0,0,0\n0,1,1,0,0,0\n", ["row 3", "column t"]),
        ("t,xd,yd,thetad,vd,wd\n0,0,0,nan,0,0\n", ["row 2", "column thetad"]),
        ("t,xd,yd,thetad,vd,wd\n0,0,0,0,0\n", ["row 2", "column wd"]),
        ("t,xd,yd,thetad,vd,wd\n", ["no data rows"]),
        ("", ["empty"]),
    ],
)
def test_csv_errors_name_row_and_column(tmp_path, text, words):
    write(tmp_path, text)
    with pytest.raises(ValueError) as info:
        build_reference({"kind": "csv", "path": "ref.csv"}, tmp_path)
    for word in words:
        assert word in str(info.value)


def test_build_reference_kinds_and_errors(tmp_path):
    circle = build_reference({"kind": "circle", "vd": 0.3, "wd": 0.1}, tmp_path)
    assert isinstance(circle, Circle) and circle.mu1 == 0.3
    point = build_reference({"kind": "point", "x": 1, "y": 2}, tmp_path)
    assert point.sample(5.0)[:3] == (1.0, 2.0, 0.0)
    stop = build_reference({"kind": "circle_then_stop", "stop_time": 5, "k1": 0.5}, tmp_path)
    assert stop.ramp == pytest.approx(1.0) and stop.k1 == pytest.approx(0.5)
    lem = build_reference({"kind": "lemniscate", "scale": 1.0, "period": 30.0}, tmp_path)
    assert lem.mu1 > 0
    with pytest.raises(ValueError, match="unknown kind 'spiral'"):
        build_reference({"kind": "spiral"}, tmp_path)
    with pytest.raises(ValueError, match="missing key 'kind'"):
        build_reference({}, tmp_path)
    with pytest.raises(ValueError, match=r"unknown key.*radius"):
        build_reference({"kind": "circle", "radius": 2}, tmp_path)
    with pytest.raises(ValueError, match="missing key 'path'"):
        build_reference({"kind": "csv"}, tmp_path)
    with pytest.raises(ValueError, match="vd must be a number"):
        build_reference({"kind": "circle", "vd": "fast"}, tmp_path)
    with pytest.raises(ValueError, match="cannot read"):
        build_reference({"kind": "csv", "path": "nope.csv"}, tmp_path)

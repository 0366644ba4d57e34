"""References: the virtual robot (3) xd' = vd cos thd, yd' = vd sin thd, thd' = wd.

Every reference samples its pose, velocities and accelerations at a time t
(:class:`ReferenceSample`) and reports its own maxima, the quantities bounded by Assumption 2:
``mu1 = max |vd|``, ``mu2 = max |wd|``, ``k1 = max |vd'|``, ``k2 = max |wd'|``.

Kinds (the scenario's [reference] table, see :func:`build_reference`):

- ``circle``: constant vd, wd from (x0, y0, theta0), in closed form.
- ``point``: the virtual robot at rest at (x, y, theta): pure stabilization.
- ``circle_then_stop``: the circle until ``stop_time``; then vd and wd ramp linearly to zero
  over one common duration tau = max(|vd|/a1, |wd|/a2), where a1, a2 are the allowed
  decelerations (the table's k1, k2, default 1.0 each, the paper's k1 = k2), and the virtual
  robot rests where it stopped. Because vd/wd stays constant during the ramp the path stays on
  the same circle, so the pose is continuous and in closed form. (A pose jump at the stop would
  leave an error the law practically never removes: after 70 s of circling eta ~ 1e-9.)
- ``lemniscate``: the figure eight of Gerono, xd = x0 + a sin(phi), yd = y0 + (a/2) sin(2 phi),
  phi = 2 pi t / period, from flat outputs (Remark 1): thd = atan2(yd', xd') (made continuous),
  vd = |(xd', yd')| > 0, wd = (yd'' xd' - xd'' yd')/vd^2; its maxima are computed on a grid of
  LEMNISCATE_GRID points over one period and raised by the relative margin LEMNISCATE_MARGIN so
  that they bound the values between grid points.
- ``csv``: a table with columns t, xd, yd, thetad, vd, wd (header row; t strictly increasing),
  interpolated linearly, holding the first row before the start and the last row past the end;
  vd', wd' are the slopes of the table's segments (0 outside it).
"""

from __future__ import annotations

import bisect
import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from controller_service.laws.base import ReferenceSample
from protocol.messages import ANGLE_MAX, POSITION_MAX, SPEED_MAX, TURN_RATE_MAX

LEMNISCATE_GRID = 20001
LEMNISCATE_MARGIN = 1e-4
DEFAULT_DECELERATION = 1.0


@runtime_checkable
class Reference(Protocol):
    """A virtual robot (3): ``sample(t)`` and its own maxima mu1, mu2, k1, k2."""

    mu1: float
    mu2: float
    k1: float
    k2: float

    def sample(self, t: float) -> ReferenceSample: ...


def _arc_pose(
    x0: float, y0: float, theta0: float, vd: float, wd: float, heading: float, distance: float
) -> tuple[float, float]:
    """Position on the circle (or line if wd = 0) of curvature wd/vd through (x0, y0, theta0),
    at ``heading`` (circle) or after ``distance`` along the line."""
    if wd != 0.0:
        radius = vd / wd
        return (
            x0 + radius * (math.sin(heading) - math.sin(theta0)),
            y0 - radius * (math.cos(heading) - math.cos(theta0)),
        )
    return x0 + distance * math.cos(theta0), y0 + distance * math.sin(theta0)


def _arc_pose_array(
    x0: float,
    y0: float,
    theta0: float,
    vd: float,
    wd: float,
    heading: np.ndarray,
    distance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_arc_pose` at arrays of headings and distances."""
    if wd != 0.0:
        radius = vd / wd
        return (
            x0 + radius * (np.sin(heading) - math.sin(theta0)),
            y0 - radius * (np.cos(heading) - math.cos(theta0)),
        )
    return x0 + distance * math.cos(theta0), y0 + distance * math.sin(theta0)


def _full(t: np.ndarray, *values: float) -> tuple[np.ndarray, ...]:
    return tuple(np.full(np.shape(t), float(v)) for v in values)


def sample_array(reference: Any, t: np.ndarray) -> ReferenceSample:
    """The reference at every time of the array ``t``: a :class:`ReferenceSample` of arrays of
    t's shape. Uses the reference's own ``sample_array`` (every kind here has one: the same
    formulas on numpy, equal to ``sample`` to rounding), else ``sample`` element by element.
    """
    own = getattr(reference, "sample_array", None)
    if own is not None:
        shape = np.shape(t)
        return ReferenceSample(
            *(v if np.shape(v) == shape else np.broadcast_to(v, shape) for v in own(t))
        )
    samples = [reference.sample(float(tk)) for tk in np.ravel(t)]
    return ReferenceSample(
        *(np.array([s[i] for s in samples], dtype=float).reshape(np.shape(t)) for i in range(7))
    )


@dataclass(frozen=True)
class Circle:
    """Constant vd, wd from (x0, y0, theta0): the paper's tracking reference (vd = 0.5,
    wd = 0.2)."""

    vd: float = 0.5
    wd: float = 0.2
    x0: float = 0.0
    y0: float = 0.0
    theta0: float = 0.0

    @property
    def mu1(self) -> float:
        return abs(self.vd)

    @property
    def mu2(self) -> float:
        return abs(self.wd)

    k1 = 0.0
    k2 = 0.0

    def sample(self, t: float) -> ReferenceSample:
        heading = self.theta0 + self.wd * t
        xd, yd = _arc_pose(self.x0, self.y0, self.theta0, self.vd, self.wd, heading, self.vd * t)
        return ReferenceSample(xd, yd, heading, self.vd, self.wd, 0.0, 0.0)

    def sample_array(self, t: np.ndarray) -> ReferenceSample:
        t = np.asarray(t, dtype=float)
        heading = self.theta0 + self.wd * t
        xd, yd = _arc_pose_array(
            self.x0, self.y0, self.theta0, self.vd, self.wd, heading, self.vd * t
        )
        return ReferenceSample(xd, yd, heading, *_full(t, self.vd, self.wd, 0.0, 0.0))


@dataclass(frozen=True)
class Point:
    """The virtual robot at rest at (x, y, theta): the stabilization task."""

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0
    mu1 = 0.0
    mu2 = 0.0
    k1 = 0.0
    k2 = 0.0

    def sample(self, t: float) -> ReferenceSample:
        return ReferenceSample(self.x, self.y, self.theta, 0.0, 0.0, 0.0, 0.0)

    def sample_array(self, t: np.ndarray) -> ReferenceSample:
        return ReferenceSample(
            *_full(np.asarray(t), self.x, self.y, self.theta, 0.0, 0.0, 0.0, 0.0)
        )


class CircleThenStop:
    """The circle until ``stop_time``, then a linear ramp of vd and wd to zero over
    tau = max(|vd|/decel1, |wd|/decel2), then rest (module docstring)."""

    def __init__(
        self,
        vd: float = 0.5,
        wd: float = 0.2,
        x0: float = 0.0,
        y0: float = 0.0,
        theta0: float = 0.0,
        stop_time: float = 70.0,
        decel1: float = DEFAULT_DECELERATION,
        decel2: float = DEFAULT_DECELERATION,
    ) -> None:
        if not (decel1 > 0.0 and decel2 > 0.0):
            raise ValueError("[reference] circle_then_stop: k1, k2 (the decelerations) must be > 0")
        if not (stop_time >= 0.0):
            raise ValueError("[reference] circle_then_stop: stop_time must be >= 0")
        self.vd, self.wd = float(vd), float(wd)
        self.x0, self.y0, self.theta0 = float(x0), float(y0), float(theta0)
        self.stop_time = float(stop_time)
        self.ramp = max(abs(self.vd) / decel1, abs(self.wd) / decel2)
        self.mu1 = abs(self.vd)
        self.mu2 = abs(self.wd)
        self.k1 = abs(self.vd) / self.ramp if self.ramp > 0.0 else 0.0
        self.k2 = abs(self.wd) / self.ramp if self.ramp > 0.0 else 0.0

    def rest_pose(self) -> tuple[float, float, float]:
        """Where the virtual robot comes to rest (x, y, theta); choose x0, y0, theta0 from it
        to make the stop land on a given point, e.g. the paper's (0, 0, 0)."""
        s = self.sample(self.stop_time + self.ramp + 1.0)
        return s.xd, s.yd, s.thetad

    def _progress(self, t: float) -> tuple[float, float, float]:
        """(scale s of vd and wd, elapsed 'full-speed-equivalent' time, ramp-phase flag):
        heading = theta0 + wd * equivalent, distance = vd * equivalent."""
        if t <= self.stop_time:
            return 1.0, t, 0.0
        s = min(t - self.stop_time, self.ramp)
        if self.ramp == 0.0:
            return 0.0, self.stop_time, 0.0
        if t - self.stop_time >= self.ramp:
            return 0.0, self.stop_time + 0.5 * self.ramp, 0.0
        return 1.0 - s / self.ramp, self.stop_time + s - s * s / (2.0 * self.ramp), 1.0

    def sample(self, t: float) -> ReferenceSample:
        scale, equivalent, ramping = self._progress(t)
        heading = self.theta0 + self.wd * equivalent
        xd, yd = _arc_pose(
            self.x0, self.y0, self.theta0, self.vd, self.wd, heading, self.vd * equivalent
        )
        dvd = -self.k1 * math.copysign(1.0, self.vd) * ramping if self.vd != 0.0 else 0.0
        dwd = -self.k2 * math.copysign(1.0, self.wd) * ramping if self.wd != 0.0 else 0.0
        return ReferenceSample(xd, yd, heading, self.vd * scale, self.wd * scale, dvd, dwd)

    def sample_array(self, t: np.ndarray) -> ReferenceSample:
        """:meth:`sample` at every time of ``t`` (the same cases of :meth:`_progress`)."""
        t = np.asarray(t, dtype=float)
        before = t <= self.stop_time
        if self.ramp == 0.0:
            scale = np.where(before, 1.0, 0.0)
            equivalent = np.where(before, t, self.stop_time)
            ramping = np.zeros(t.shape)
        else:
            s = np.minimum(t - self.stop_time, self.ramp)
            done = t - self.stop_time >= self.ramp
            ramp_scale = 1.0 - s / self.ramp
            ramp_eq = self.stop_time + s - s * s / (2.0 * self.ramp)
            scale = np.where(before, 1.0, np.where(done, 0.0, ramp_scale))
            equivalent = np.where(
                before, t, np.where(done, self.stop_time + 0.5 * self.ramp, ramp_eq)
            )
            ramping = np.where(before | done, 0.0, 1.0)
        heading = self.theta0 + self.wd * equivalent
        xd, yd = _arc_pose_array(
            self.x0, self.y0, self.theta0, self.vd, self.wd, heading, self.vd * equivalent
        )
        dvd = -self.k1 * math.copysign(1.0, self.vd) * ramping if self.vd != 0.0 else 0.0 * t
        dwd = -self.k2 * math.copysign(1.0, self.wd) * ramping if self.wd != 0.0 else 0.0 * t
        return ReferenceSample(xd, yd, heading, self.vd * scale, self.wd * scale, dvd, dwd)


class Lemniscate:
    """The figure eight of Gerono built from flat outputs (Remark 1), module docstring."""

    def __init__(
        self, scale: float = 2.0, period: float = 60.0, x0: float = 0.0, y0: float = 0.0
    ) -> None:
        if not (scale > 0.0 and math.isfinite(scale)):
            raise ValueError("[reference] lemniscate: scale must be a finite number > 0")
        if not (period > 0.0 and math.isfinite(period)):
            raise ValueError("[reference] lemniscate: period must be a finite number > 0")
        self.scale, self.period = float(scale), float(period)
        self.x0, self.y0 = float(x0), float(y0)
        self.omega = 2.0 * math.pi / self.period
        grid = np.linspace(0.0, self.period, LEMNISCATE_GRID)
        try:
            samples = [self.sample(float(t)) for t in grid]
        except (ArithmeticError, ValueError):  # under- or overflow of the derivatives
            samples = []
        margin = 1.0 + LEMNISCATE_MARGIN
        self.mu1 = margin * max((abs(s.vd) for s in samples), default=math.nan)
        self.mu2 = margin * max((abs(s.wd) for s in samples), default=math.nan)
        self.k1 = margin * max((abs(s.dvd) for s in samples), default=math.nan)
        self.k2 = margin * max((abs(s.dwd) for s in samples), default=math.nan)
        if not all(math.isfinite(v) for v in (self.mu1, self.mu2, self.k1, self.k2)):
            raise ValueError(
                f"[reference] lemniscate: scale = {self.scale:g}, period = {self.period:g} give "
                "no finite velocities and accelerations (under- or overflow)"
            )

    def sample(self, t: float) -> ReferenceSample:
        a, w = self.scale, self.omega
        phi = w * t
        s1, c1 = math.sin(phi), math.cos(phi)
        s2, c2 = math.sin(2.0 * phi), math.cos(2.0 * phi)
        dx, dy = a * w * c1, a * w * c2
        ddx, ddy = -a * w * w * s1, -2.0 * a * w * w * s2
        dddx, dddy = -a * w**3 * c1, -4.0 * a * w**3 * c2
        speed2 = dx * dx + dy * dy
        vd = math.sqrt(speed2)
        num = ddy * dx - ddx * dy
        wd = num / speed2
        dvd = (dx * ddx + dy * ddy) / vd
        dnum = dddy * dx - dddx * dy
        dwd = (dnum * speed2 - num * 2.0 * (dx * ddx + dy * ddy)) / (speed2 * speed2)
        # atan2 of the velocity turned by +90 degrees never crosses the branch cut (c1 = 0
        # implies c2 = -1), so this heading is continuous for all t.
        thetad = math.atan2(c1, -c2) - 0.5 * math.pi
        return ReferenceSample(self.x0 + a * s1, self.y0 + 0.5 * a * s2, thetad, vd, wd, dvd, dwd)

    def sample_array(self, t: np.ndarray) -> ReferenceSample:
        """:meth:`sample` at every time of ``t`` (the same formulas on numpy arrays)."""
        a, w = self.scale, self.omega
        phi = w * np.asarray(t, dtype=float)
        s1, c1 = np.sin(phi), np.cos(phi)
        s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
        dx, dy = a * w * c1, a * w * c2
        ddx, ddy = -a * w * w * s1, -2.0 * a * w * w * s2
        dddx, dddy = -a * w**3 * c1, -4.0 * a * w**3 * c2
        speed2 = dx * dx + dy * dy
        vd = np.sqrt(speed2)
        num = ddy * dx - ddx * dy
        wd = num / speed2
        dvd = (dx * ddx + dy * ddy) / vd
        dnum = dddy * dx - dddx * dy
        dwd = (dnum * speed2 - num * 2.0 * (dx * ddx + dy * ddy)) / (speed2 * speed2)
        thetad = np.arctan2(c1, -c2) - 0.5 * math.pi
        return ReferenceSample(self.x0 + a * s1, self.y0 + 0.5 * a * s2, thetad, vd, wd, dvd, dwd)


CSV_COLUMNS = ("t", "xd", "yd", "thetad", "vd", "wd")


class CsvReference:
    """A recorded reference: linear interpolation, holding the end rows (module docstring)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        rows = _read_csv(self.path)
        self.t = [row[0] for row in rows]
        self.columns = [[row[i] for row in rows] for i in range(1, 6)]
        vd, wd = self.columns[3], self.columns[4]
        self.dvd = [(vd[i + 1] - vd[i]) / (self.t[i + 1] - self.t[i]) for i in range(len(rows) - 1)]
        self.dwd = [(wd[i + 1] - wd[i]) / (self.t[i + 1] - self.t[i]) for i in range(len(rows) - 1)]
        self.mu1 = max(abs(v) for v in vd)
        self.mu2 = max(abs(v) for v in wd)
        self.k1 = max((abs(v) for v in self.dvd), default=0.0)
        self.k2 = max((abs(v) for v in self.dwd), default=0.0)
        if not all(math.isfinite(v) for v in (self.mu1, self.mu2, self.k1, self.k2)):
            raise ValueError(
                f"[reference] csv path {self.path}: the slopes of vd, wd overflow "
                "(values too large or rows too close in t)"
            )

    def sample(self, t: float) -> ReferenceSample:
        times = self.t
        if t <= times[0]:
            return ReferenceSample(*(col[0] for col in self.columns), 0.0, 0.0)
        if t >= times[-1]:
            return ReferenceSample(*(col[-1] for col in self.columns), 0.0, 0.0)
        i = bisect.bisect_right(times, t) - 1
        w = (t - times[i]) / (times[i + 1] - times[i])
        values = (col[i] + w * (col[i + 1] - col[i]) for col in self.columns)
        return ReferenceSample(*values, self.dvd[i], self.dwd[i])

    def sample_array(self, t: np.ndarray) -> ReferenceSample:
        """:meth:`sample` at every time of ``t`` (the same interpolation on numpy arrays)."""
        t = np.asarray(t, dtype=float)
        times = np.asarray(self.t)
        cols = [np.asarray(c) for c in self.columns]
        before, after = t <= times[0], t >= times[-1]
        if times.size < 2:
            return ReferenceSample(*(np.full(t.shape, c[0]) for c in cols), 0.0 * t, 0.0 * t)
        i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, times.size - 2)
        w = (t - times[i]) / (times[i + 1] - times[i])
        values = [
            np.where(before, c[0], np.where(after, c[-1], c[i] + w * (c[i + 1] - c[i])))
            for c in cols
        ]
        inside = ~(before | after)
        dvd = np.where(inside, np.asarray(self.dvd)[i], 0.0)
        dwd = np.where(inside, np.asarray(self.dwd)[i], 0.0)
        return ReferenceSample(*values, dvd, dwd)


def _read_csv(path: Path) -> list[tuple[float, ...]]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(
            f"[reference] csv path {path}: cannot read ({exc.strerror or exc})"
        ) from exc
    except UnicodeDecodeError as exc:
        raise ValueError(f"[reference] csv path {path}: not UTF-8 text ({exc.reason})") from exc
    try:
        return _parse_csv(path, text)
    except csv.Error as exc:
        raise ValueError(f"[reference] csv path {path}: not CSV ({exc})") from exc


def _parse_csv(path: Path, text: str) -> list[tuple[float, ...]]:
    where = f"[reference] csv path {path}"
    reader = csv.reader(text.splitlines())
    try:
        header = [name.strip() for name in next(reader)]
    except StopIteration:
        raise ValueError(f"{where}: empty file (no header row)") from None
    missing = [name for name in CSV_COLUMNS if name not in header]
    if missing:
        raise ValueError(f"{where}: missing column(s) {', '.join(missing)}")
    index = [header.index(name) for name in CSV_COLUMNS]
    rows: list[tuple[float, ...]] = []
    for line_no, raw in enumerate(reader, start=2):
        if not raw or all(not cell.strip() for cell in raw):
            continue
        values = []
        for name, i in zip(CSV_COLUMNS, index, strict=True):
            cell = raw[i].strip() if i < len(raw) else ""
            try:
                value = float(cell)
            except ValueError:
                raise ValueError(
                    f"{where}: row {line_no} column {name}: {cell!r} is not a number"
                ) from None
            if not math.isfinite(value):
                raise ValueError(f"{where}: row {line_no} column {name}: {cell!r} is not finite")
            values.append(value)
        if rows and not values[0] > rows[-1][0]:
            raise ValueError(
                f"{where}: row {line_no} column t: {values[0]!r} is not after the "
                f"previous row's {rows[-1][0]!r} (t must increase strictly)"
            )
        rows.append(tuple(values))
    if not rows:
        raise ValueError(f"{where}: no data rows")
    return rows


_DESIGN_BOUND_KEYS = ("mu1", "mu2", "k1", "k2")
_KINDS: dict[str, tuple[dict[str, Any], tuple[str, ...]]] = {
    # kind: (keys with their defaults (None = required), extra allowed keys)
    "circle": ({"vd": 0.5, "wd": 0.2, "x0": 0.0, "y0": 0.0, "theta0": 0.0}, ()),
    "point": ({"x": 0.0, "y": 0.0, "theta": 0.0}, ()),
    "circle_then_stop": (
        {"vd": 0.5, "wd": 0.2, "x0": 0.0, "y0": 0.0, "theta0": 0.0, "stop_time": 70.0},
        (),
    ),
    "lemniscate": ({"scale": 2.0, "period": 60.0, "x0": 0.0, "y0": 0.0}, ()),
    "csv": ({"path": None}, ()),
}


# Declared ranges of the numbers (docs/scenario.md, "Errors"): positions and speeds within what a
# State message may carry (protocol.messages), times within the scenario's own limits.
MAX_MAGNITUDE = 1e9
_RANGES: dict[str, tuple[float, float]] = {
    "vd": (-SPEED_MAX, SPEED_MAX),
    "wd": (-TURN_RATE_MAX, TURN_RATE_MAX),
    "x0": (-POSITION_MAX, POSITION_MAX),
    "y0": (-POSITION_MAX, POSITION_MAX),
    "x": (-POSITION_MAX, POSITION_MAX),
    "y": (-POSITION_MAX, POSITION_MAX),
    "theta0": (-ANGLE_MAX, ANGLE_MAX),
    "theta": (-ANGLE_MAX, ANGLE_MAX),
    "stop_time": (0.0, 1e7),
    "scale": (1e-6, POSITION_MAX),
    "period": (1e-3, 1e7),
    **{key: (0.0, MAX_MAGNITUDE) for key in _DESIGN_BOUND_KEYS},
}


def _number(kind: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"[reference] {kind}: {key} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"[reference] {kind}: {key} must be finite, got {value!r}")
    low, high = _RANGES.get(key, (-MAX_MAGNITUDE, MAX_MAGNITUDE))
    if not low <= value <= high:
        raise ValueError(f"[reference] {kind}: {key} must be in [{low:g}, {high:g}], got {value!r}")
    return value


def check_table(table: Mapping[str, Any]) -> str:
    """Check a [reference] table without building it (no file is read): the kind, the keys,
    every number finite and within its range, a csv path a plain string. Returns the kind;
    raises ValueError naming the key."""
    if not isinstance(table, Mapping):
        raise ValueError("[reference] must be a table")
    if "kind" not in table:
        raise ValueError("[reference]: missing key 'kind'")
    kind = table["kind"]
    if not isinstance(kind, str) or kind not in _KINDS:
        raise ValueError(
            f"[reference]: unknown kind {kind!r} (expected one of {', '.join(_KINDS)})"
        )
    defaults, _extra = _KINDS[kind]
    allowed = {"kind", *defaults, *_DESIGN_BOUND_KEYS}
    unknown = sorted(map(str, set(table) - allowed))
    if unknown:
        raise ValueError(f"[reference] {kind}: unknown key(s) {', '.join(unknown)}")
    for key in _DESIGN_BOUND_KEYS:
        if key in table:
            _number(kind, key, table[key])
    if kind == "circle_then_stop":
        for key in ("k1", "k2"):  # its decelerations
            if key in table and not table[key] > 0.0:
                raise ValueError(
                    f"[reference] circle_then_stop: {key} (a deceleration) must be > 0, "
                    f"got {table[key]!r}"
                )
    if kind == "csv":
        if "path" not in table:
            raise ValueError("[reference] csv: missing key 'path'")
        path = table["path"]
        if not isinstance(path, str) or not path.strip():
            raise ValueError(f"[reference] csv: path must be a file name (a string), got {path!r}")
        if any(ord(c) < 32 for c in path):
            raise ValueError(f"[reference] csv: path holds control characters: {path!r}")
        return kind
    for key, default in defaults.items():
        _number(kind, key, table.get(key, default))
    return kind


def build_reference(table: Mapping[str, Any], base_dir: Path) -> Reference:
    """The reference named by a scenario's [reference] table (docs/scenario.md).

    Unknown kinds, unknown keys, missing required keys, non-numbers and numbers out of range
    raise ValueError naming them (:func:`check_table`). The design bounds mu1, mu2, k1, k2 are
    allowed in every kind (the loader reads them); circle_then_stop also uses k1, k2 as its
    deceleration rates (default 1.0 each).
    """
    kind = check_table(table)
    if kind == "csv":
        path = Path(table["path"])
        return CsvReference(path if path.is_absolute() else Path(base_dir) / path)
    defaults, _extra = _KINDS[kind]
    values = {key: _number(kind, key, table.get(key, default)) for key, default in defaults.items()}
    if kind == "circle":
        return Circle(**values)
    if kind == "point":
        return Point(**values)
    if kind == "circle_then_stop":
        decel1 = _number(kind, "k1", table.get("k1", DEFAULT_DECELERATION))
        decel2 = _number(kind, "k2", table.get("k2", DEFAULT_DECELERATION))
        return CircleThenStop(**values, decel1=decel1, decel2=decel2)
    return Lemniscate(**values)

"""The one guard around a law's ``update``: a law that fails is a fault of the law, named.

Every caller of a law's ``update`` goes through here (the controller service's
:class:`~controller_service.service.ControlCore`, ``hil sim``'s loops, the batch path of
``hil sweep``, ``hil margin``'s loops), so a law that

- raises (``kind = "exception"``),
- returns something else than a pair ``(ControlOutput, memory)`` whose output has ``tau1``,
  ``tau2`` (numbers, or arrays of numbers) and a ``telemetry`` mapping (``"wrong_type"``), or
- returns a torque that is not finite (``"non_finite"``), or
- cannot be built in the controller process (``"build"``: its module or constructor raised
  there, though ``hil`` built it before starting the services; a path relative to another
  working directory, a resource only one process may hold)

gets the same answer everywhere: a :class:`LawFault` record (the law, the time, the inputs of
the failing call, what went wrong, the traceback) and :meth:`LawFault.sentence`, one sentence
that the verdict quotes first (docs/own-controller.md, "When your law fails"). A torque outside
the limits (2) is not a fault: the callers clamp or count it as before.
"""

from __future__ import annotations

import math
import traceback as tb
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from controller_service.laws.base import ReferenceSample, RobotState
from protocol.hoplog import LAW_FAULT_FILE

EXCEPTION, NON_FINITE, WRONG_TYPE, BUILD = "exception", "non_finite", "wrong_type", "build"
KINDS = (EXCEPTION, NON_FINITE, WRONG_TYPE, BUILD)
EXPECTED = "(ControlOutput, memory)"


def _number(value: Any) -> float | None:
    """A float for the record (None: not a finite number, as JSON can carry it)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _fields(values: Any, names: tuple[str, ...], robot: int | None) -> dict[str, float | None]:
    """The named fields of a state or reference (robot ``robot``'s when they are arrays;
    none when they are arrays and no robot is named: a batch's call failed as a whole)."""
    out: dict[str, float | None] = {}
    if robot is None and any(np.ndim(getattr(values, n, 0.0)) > 0 for n in names):
        return out
    for name in names:
        value = getattr(values, name, None)
        if robot is not None and value is not None and np.ndim(value) > 0:
            flat = np.ravel(value)
            value = flat[robot] if flat.size > robot else flat[-1]
        out[name] = _number(value)
    return out


def _words(values: Mapping[str, float | None]) -> str:
    """ "the state x = 0.52, y = ..." (a batch's call that failed as a whole: no one state)."""
    if not values:
        return "the states of a batch of robots"
    return "the state " + ", ".join(
        f"{k} = {'nan' if v is None else f'{v:.4g}'}" for k, v in values.items()
    )


@dataclass(frozen=True)
class LawFault:
    """One failing call of a law's ``update`` (module docstring): ``law`` its name, ``where``
    its import path "module:Class", ``kind`` one of :data:`KINDS`, ``t_s`` the law time of the
    call, ``state`` and ``reference`` its inputs (for a batch: robot ``robot``'s), ``detail``
    the exception's repr, the bad torque or what was returned, ``traceback`` the exception's
    (empty when none)."""

    law: str
    where: str
    kind: str
    t_s: float | None
    state: dict[str, float | None]
    reference: dict[str, float | None]
    detail: str
    traceback: str = ""
    robot: int | None = None

    def sentence(self, details: str = LAW_FAULT_FILE) -> str:
        """One sentence: the law, what it did, when and for which input; ``details``: the file
        that holds the record (its traceback)."""
        what = {
            EXCEPTION: f"raised {self.detail}",
            NON_FINITE: f"returned a non-finite torque {self.detail}",
            WRONG_TYPE: f"returned {self.detail} instead of {EXPECTED}",
        }.get(self.kind, f"failed ({self.kind}: {self.detail})")
        when = "at t = ? s" if self.t_s is None else f"at t = {self.t_s:.6g} s"
        more = "traceback" if self.traceback else "details"
        if self.kind == BUILD:
            where = f" ({self.where})" if self.where != self.law else ""
            return (
                f"the law {self.law}{where} could not be built in the controller process: it "
                f"raised {self.detail} ({more} in {details})"
            )
        return (
            f"the law {self.law} ({self.where}) {what} {when} for {_words(self.state)} "
            f"({more} in {details})"
        )

    def to_dict(self) -> dict[str, Any]:
        """The record as JSON can carry it (numbers that are not finite are None)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LawFault:
        """The record back from :meth:`to_dict` (unknown keys ignored: a newer writer)."""
        names = {"law", "where", "kind", "t_s", "state", "reference", "detail", "traceback"}
        values = {k: data[k] for k in names if k in data}
        robot = data.get("robot")
        return cls(
            law=str(values.get("law", "?")),
            where=str(values.get("where", "?")),
            kind=str(values.get("kind", "?")),
            t_s=_number(values.get("t_s")),
            state={str(k): _number(v) for k, v in dict(values.get("state") or {}).items()},
            reference={str(k): _number(v) for k, v in dict(values.get("reference") or {}).items()},
            detail=str(values.get("detail", "")),
            traceback=str(values.get("traceback", "")),
            robot=robot if isinstance(robot, int) and not isinstance(robot, bool) else None,
        )

    def for_robot(self, robot: int, t: Any, state: Any, ref: Any) -> LawFault:
        """The same failure as robot ``robot`` of a batch saw it (its time and inputs)."""
        return replace(
            self,
            robot=robot,
            t_s=_number(np.ravel(t)[robot] if np.ndim(t) else t),
            state=_fields(state, RobotState._fields, robot),
            reference=_fields(ref, ReferenceSample._fields, robot),
        )


class LawFaultError(Exception):
    """A law's ``update`` failed (:class:`LawFault` in ``fault``)."""

    def __init__(self, fault: LawFault) -> None:
        super().__init__(fault.sentence())
        self.fault = fault


def law_names(controller: Any) -> tuple[str, str]:
    """(the law's name, its import path "module:Class")."""
    inner = getattr(controller, "law", None)  # hil.law.batch.PerRobot wraps the user's law
    obj = inner if inner is not None and hasattr(inner, "update") else controller
    cls = type(obj)
    return str(getattr(obj, "name", cls.__name__)), f"{cls.__module__}:{cls.__qualname__}"


def fault(
    controller: Any,
    kind: str,
    t: Any,
    state: Any,
    ref: Any,
    detail: str,
    trace: str = "",
    robot: int | None = None,
) -> LawFault:
    """The record of one failing call (robot ``robot``'s inputs when they are arrays)."""
    law, where = law_names(controller)
    at = None if robot is None or not np.ndim(t) else robot
    return LawFault(
        law=law,
        where=where,
        kind=kind,
        t_s=_number(np.ravel(t)[at] if at is not None else t),
        state=_fields(state, RobotState._fields, robot),
        reference=_fields(ref, ReferenceSample._fields, robot),
        detail=detail,
        traceback=trace,
        robot=robot,
    )


def build_fault(law: str, where: str, exc: BaseException) -> LawFault:
    """The record of a law that could not be built (called in the ``except`` that caught
    ``exc``: the traceback is the current one)."""
    return LawFault(
        law=law,
        where=where,
        kind=BUILD,
        t_s=None,
        state={},
        reference={},
        detail=repr(exc),
        traceback=tb.format_exc(),
    )


def _what_returned(result: Any) -> str | None:
    """What is wrong with ``update``'s return (None: a pair whose output has the fields)."""
    if not isinstance(result, tuple | list) or len(result) != 2:
        kind = type(result).__name__
        size = f" of {len(result)}" if isinstance(result, tuple | list) else ""
        return f"a {kind}{size}"
    out = result[0]
    if not all(hasattr(out, name) for name in ("tau1", "tau2", "telemetry")):
        return f"({type(out).__name__}, ...)"
    if not isinstance(out.telemetry, Mapping):
        return f"an output whose telemetry is a {type(out.telemetry).__name__}, not a mapping"
    return None


def call_update(
    controller: Any, t: Any, dt: float, state: Any, ref: Any, memory: Any
) -> tuple[Any, Any]:
    """``controller.update(t, dt, state, ref, memory)``; an exception or a return that is not
    ``(ControlOutput-like, memory)`` raises :class:`LawFaultError` (torques not checked)."""
    try:
        result = controller.update(t, dt, state, ref, memory)
    except Exception as exc:  # the user's code may raise anything
        record = fault(controller, EXCEPTION, t, state, ref, repr(exc), tb.format_exc())
        raise LawFaultError(record) from exc
    wrong = _what_returned(result)
    if wrong is not None:
        raise LawFaultError(fault(controller, WRONG_TYPE, t, state, ref, wrong))
    return result[0], result[1]


def bad_torques(tau1: Any, tau2: Any, robot: int | None = None) -> str | None:
    """ "tau1 = nan" (and/or tau2) when a torque is not finite, None when both are; robot
    ``robot``'s of arrays. A torque that is no number is reported as such."""
    words = []
    for name, value in (("tau1", tau1), ("tau2", tau2)):
        if robot is not None and np.ndim(value) > 0:
            flat = np.ravel(value)
            value = flat[robot] if flat.size > robot else flat[-1]
        try:
            if isinstance(value, str | bytes):  # float() would read "1" as a number
                raise TypeError(name)
            x = float(value)
        except (TypeError, ValueError):
            return f"{name} of type {type(value).__name__}"
        if not math.isfinite(x):
            words.append(f"{name} = {x!r}")
    return ", ".join(words) or None


def checked_update(
    controller: Any, t: Any, dt: float, state: Any, ref: Any, memory: Any
) -> tuple[Any, Any]:
    """:func:`call_update`, and a torque that is not finite raises :class:`LawFaultError`
    too (on arrays: the first robot whose torque is not finite, named by ``robot``)."""
    out, memory_next = call_update(controller, t, dt, state, ref, memory)
    tau1, tau2 = out.tau1, out.tau2
    if np.ndim(tau1) == 0 and np.ndim(tau2) == 0:
        bad = bad_torques(tau1, tau2)
        if bad is None:
            return out, memory_next
        kind = WRONG_TYPE if " of type " in bad else NON_FINITE
        detail = f"a torque {bad}" if kind == WRONG_TYPE else bad
        raise LawFaultError(fault(controller, kind, t, state, ref, detail))
    try:
        a = np.asarray(tau1, dtype=float)
        b = np.asarray(tau2, dtype=float)
    except (TypeError, ValueError):
        detail = f"torques of types {type(tau1).__name__}, {type(tau2).__name__}"
        raise LawFaultError(fault(controller, WRONG_TYPE, t, state, ref, detail)) from None
    a, b = np.broadcast_arrays(a, b)
    bad_at = np.flatnonzero(~(np.isfinite(a) & np.isfinite(b)))
    if bad_at.size:
        i = int(bad_at[0])
        detail = bad_torques(a, b, i) or "?"
        raise LawFaultError(fault(controller, NON_FINITE, t, state, ref, detail, robot=i))
    return out, memory_next

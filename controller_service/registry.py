"""Build a controller from a scenario's [controller] table (docs/scenario.md).

``law`` selects it:

- ``"unified"`` / ``"unified_boundary"``: :class:`UnifiedController` with m1, m2, l1, l2, lam,
  rho (Table 1 defaults: 0.5, 0.5, 0.5, 0.5, 1, 1; lam and rho may be ``"auto"``, see
  :func:`controller_service.design.resolve_auto`) and, for the boundary layer (19), eps1, eps2
  (default 0.1 each). The design is checked; a violation raises
  :class:`controller_service.design.DesignError` (a ValueError). ``eta_rearm = true`` (default
  false: the paper's law) wraps it in :class:`controller_service.laws.eta_rearm.
  EtaRearmController` (eta reset to 1 when the reference comes to rest; keys
  ``eta_rearm_dwell``, s, ``eta_rearm_below`` and ``eta_rearm_tol``, m: also reset z1, z2 to
  turn the robot towards the stop point while its position error exceeds it, then to stop its
  turn back as the heading crosses its target).
- ``"jiang1997"``: [7] with the sub-table [controller.jiang1997] c1, c2 (7, 0.1).
- ``"jiang2001"``: [19] with [controller.jiang2001] stab_eps, track_lam.
- ``"package.module:Class"``: a user's controller, built as ``Class(params, context)`` where
  params is the whole [controller] table without ``law``; it must satisfy the Controller
  protocol of :mod:`controller_service.laws.base`. Its module is looked up in the installed
  packages, then in the folders of ``law_path`` (:func:`law_path_for`: the scenario's folder and
  the working directory), so a ``my_law.py`` next to the scenario needs no ``PYTHONPATH``.

Sub-tables of the other baselines may sit beside a built-in law; they are not used but must be
right (checked as if their law were chosen). Any other unknown key is refused with a ValueError
naming it. :func:`check_table` checks a table without building anything (the scenario loader
calls it); a user's module is imported only by :func:`build_controller`.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import math
import re
import sys
import weakref
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from controller_service.design import resolve_auto
from controller_service.laws.base import Controller, DesignContext
from controller_service.laws.eta_rearm import EtaRearmController
from controller_service.laws.jiang1997 import Jiang1997Controller
from controller_service.laws.jiang2001 import Jiang2001Controller
from controller_service.laws.unified import UnifiedController, UnifiedParams
from protocol.paper import EPS_DEFAULT, TABLE1

BUILTIN_LAWS = ("unified", "unified_boundary", "jiang1997", "jiang2001")
_BASELINE_TABLES = ("jiang1997", "jiang2001")
# The unified law's eta re-arm (beyond the paper, off by default): controller_service.laws.eta_rearm
REARM_KEYS = ("eta_rearm", "eta_rearm_dwell", "eta_rearm_below", "eta_rearm_tol")

# Tables of user controllers (whose objects cannot be asked for one) and notes of auto lam/rho.
_user_tables: weakref.WeakKeyDictionary[Any, dict[str, Any]] = weakref.WeakKeyDictionary()
_notes: weakref.WeakKeyDictionary[Any, tuple[str, ...]] = weakref.WeakKeyDictionary()


# A user's law: "package.module:Class" (the module part absolute, so never a relative import).
_IMPORT_PATH = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[^\s:]+")


def _number(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        also = " or 'auto'" if key in ("lam", "rho") else ""
        raise ValueError(f"[controller] {key} must be a number{also}, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"[controller] {key} must be finite, got {value!r}")
    return value


def _unified_values(law: str, table: Mapping[str, Any]) -> dict[str, Any]:
    """The unified law's parameters, defaults filled; ValueError naming a bad key."""
    keys = dict(TABLE1)
    if law == "unified_boundary":
        keys.update(EPS_DEFAULT)
    unknown = sorted(map(str, set(table) - set(keys) - {"law", *_BASELINE_TABLES, *REARM_KEYS}))
    if unknown:
        hint = (
            " (eps1, eps2 need law = 'unified_boundary')" if {"eps1", "eps2"} & set(unknown) else ""
        )
        raise ValueError(f"[controller] {law}: unknown key(s) {', '.join(unknown)}{hint}")
    values: dict[str, Any] = {}
    for key, default in keys.items():
        value = table.get(key, default)
        if key in ("lam", "rho") and value == "auto":
            values[key] = value
        else:
            values[key] = _number(key, value)
    _rearm_values(table)
    return values


def _rearm_values(table: Mapping[str, Any]) -> dict[str, Any] | None:
    """The eta re-arm options (keyword arguments of :class:`EtaRearmController`), None when
    ``eta_rearm`` is off (the paper's law); ValueError naming a bad key."""
    on = table.get("eta_rearm", False)
    if not isinstance(on, bool):
        raise ValueError(f"[controller] eta_rearm must be true or false, got {on!r}")
    given = {k: table[k] for k in REARM_KEYS[1:] if k in table}
    if not on:
        if given:
            raise ValueError(f"[controller] {', '.join(sorted(given))} need eta_rearm = true")
        return None
    out = {k.removeprefix("eta_rearm_"): _number(k, v) for k, v in given.items()}
    if out.get("dwell", 1.0) <= 0.0:
        raise ValueError(f"[controller] eta_rearm_dwell must be > 0 s, got {out['dwell']!r}")
    if not 0.0 < out.get("below", 0.5) <= 1.0:
        raise ValueError(f"[controller] eta_rearm_below must be in (0, 1], got {out['below']!r}")
    if out.get("tol", 1.0) <= 0.0:
        raise ValueError(f"[controller] eta_rearm_tol must be > 0 m, got {out['tol']!r}")
    return out


def _baseline(law: str, table: Mapping[str, Any], context: DesignContext) -> Controller:
    sub = table.get(law, {})
    if not isinstance(sub, Mapping):
        raise ValueError(f"[controller.{law}] must be a table")
    cls = Jiang1997Controller if law == "jiang1997" else Jiang2001Controller
    return cls(sub, context)


def check_table(table: Mapping[str, Any]) -> str:
    """Check a [controller] table without building the law (nothing is imported): the law's
    name or import path, its keys and numbers, and any baseline sub-table beside it. Returns
    the law; raises ValueError naming the key. Design conditions need the scenario's limits
    and reference: :func:`build_controller` checks them."""
    law = table.get("law", "unified")
    if not isinstance(law, str):
        raise ValueError(f"[controller] law must be a string, got {law!r}")
    if law not in BUILTIN_LAWS and not _IMPORT_PATH.fullmatch(law):
        raise ValueError(
            f"[controller] law {law!r}: expected one of {', '.join(BUILTIN_LAWS)} "
            "or an import path 'package.module:Class'"
        )
    if law in ("unified", "unified_boundary"):
        _unified_values(law, table)
    elif law in _BASELINE_TABLES:
        unknown = sorted(map(str, set(table) - {"law", *_BASELINE_TABLES}))
        if unknown:
            raise ValueError(
                f"[controller] {law}: unknown key(s) {', '.join(unknown)} "
                f"(its parameters go in [controller.{law}])"
            )
    if law in BUILTIN_LAWS:  # a sub-table beside the law must be right too, not ignored
        for name in _BASELINE_TABLES:
            if name in table:
                _baseline(name, table, DesignContext())
    return law


def _build_unified(law: str, table: Mapping[str, Any], context: DesignContext) -> Controller:
    values = _unified_values(law, table)
    resolved = resolve_auto(values, context)
    controller: Any = UnifiedController(UnifiedParams(**resolved.params), context)
    rearm = _rearm_values(table)
    if rearm is not None:
        controller = EtaRearmController(controller, **rearm)
    if resolved.notes:
        _notes[controller] = resolved.notes
    return controller


def law_path_for(scenario_dir: str | Path | None) -> tuple[str, ...]:
    """The folders a user's law module is looked up in after the installed packages: the
    scenario's folder, then the working directory (absolute, each once). hil resolves them
    once and writes them into the run's settings, so the services find the same module."""
    folders = [Path.cwd()] if scenario_dir is None else [Path(scenario_dir), Path.cwd()]
    out: list[str] = []
    for folder in folders:
        text = str(folder.resolve())
        if text not in out:
            out.append(text)
    return tuple(out)


def _import_law_module(path: str, module_name: str, law_path: Iterable[str]) -> Any:
    """The user's module, looked up in the installed packages then in ``law_path``."""
    folders = [str(f) for f in law_path]
    # Appended, not prepended: a user's file never shadows an installed package; the folders
    # stay on sys.path because the module may import its neighbours later, mid-run.
    sys.path.extend(f for f in folders if f not in sys.path)
    importlib.invalidate_caches()  # a module written after this process started
    try:
        return importlib.import_module(module_name)
    except Exception as exc:  # the user's module may raise anything while it is imported
        where = "; looked in the installed packages"
        where += "".join(f", {f}" for f in folders)
        raise ValueError(
            f"[controller] law {path!r}: cannot import {module_name!r}: {_what(exc)}"
            + (where if isinstance(exc, ModuleNotFoundError) else "")
        ) from exc


def _build_user(
    path: str, table: Mapping[str, Any], context: DesignContext, law_path: Iterable[str] = ()
) -> Controller:
    module_name, _, class_name = path.partition(":")
    if not module_name or not class_name:
        raise ValueError(
            f"[controller] law {path!r}: expected one of {', '.join(BUILTIN_LAWS)} "
            "or an import path 'package.module:Class'"
        )
    module = _import_law_module(path, module_name, law_path)
    cls = module
    for part in class_name.split("."):
        cls = getattr(cls, part, None)
        if cls is None:
            raise ValueError(f"[controller] law {path!r}: {module_name} has no {class_name!r}")
    params = {k: v for k, v in table.items() if k != "law"}
    try:
        controller = cls(params, context)
    except Exception as exc:  # the user's constructor may raise anything
        raise ValueError(f"[controller] law {path!r}: building it failed: {_what(exc)}") from exc
    try:
        missing = [
            name
            for name in ("name", "initial_memory", "update")
            if not hasattr(controller, name)
            or (name != "name" and not callable(getattr(controller, name)))
        ]
        satisfied = not missing and isinstance(controller, Controller)
    except Exception as exc:  # a property of the user's object raised
        raise ValueError(f"[controller] law {path!r}: inspecting it failed: {_what(exc)}") from exc
    if not satisfied:
        raise ValueError(
            f"[controller] law {path!r}: the object does not satisfy the Controller protocol "
            f"(missing or not callable: {', '.join(missing) or '?'}; see "
            "controller_service.laws.base.Controller)"
        )
    _check_initial_memory(path, controller)
    # An object that is not weak-referenceable falls back to its class path in the table.
    with contextlib.suppress(TypeError):
        _user_tables[controller] = {"law": path, **params}
    return controller


def _check_initial_memory(path: str, controller: Any) -> None:
    """Every law is called as ``initial_memory(n, z1=..., z2=...)`` (the scenario's [initial]
    z1(0), z2(0)); a user's law that cannot take them is refused here, by name, not mid-run."""
    try:
        inspect.signature(controller.initial_memory).bind(None, z1=0.0, z2=0.0)
    except TypeError as exc:
        raise ValueError(
            f"[controller] law {path!r}: initial_memory must accept (n, z1=0.0, z2=0.0) "
            f"(z1(0), z2(0) of (8); a law without them ignores them): {exc}"
        ) from exc
    except ValueError:  # no signature to read (a builtin): it is called and fails, named
        pass


def _what(exc: BaseException) -> str:
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def build_controller(
    table: Mapping[str, Any], context: DesignContext, law_path: Iterable[str] = ()
) -> Controller:
    """The controller named by ``table["law"]`` (default "unified"), checked and ready; a
    user's module is looked up in the installed packages, then in ``law_path``
    (:func:`law_path_for`)."""
    law = check_table(table)
    if law in ("unified", "unified_boundary"):
        return _build_unified(law, table, context)
    if law in _BASELINE_TABLES:
        return _baseline(law, table, context)
    return _build_user(law, table, context, law_path)


def resolved_controller_table(controller: Any) -> dict[str, Any]:
    """Every parameter the controller actually uses (auto lam/rho resolved), as a
    [controller] table for scenario.resolved.toml."""
    resolved = getattr(controller, "resolved_table", None)
    if callable(resolved):
        return dict(resolved())
    try:
        table = _user_tables.get(controller)
    except TypeError:
        table = None
    if table is not None:
        return dict(table)
    cls = type(controller)
    return {"law": f"{cls.__module__}:{cls.__qualname__}"}


def resolved_notes(controller: Any) -> tuple[str, ...]:
    """How "auto" lam/rho were resolved (empty when nothing was auto)."""
    try:
        return _notes.get(controller, ())
    except TypeError:
        return ()

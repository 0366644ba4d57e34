"""A small math namespace so every law and the plant are written once.

The real-time path steps one robot on plain Python floats (about 2 us a step); the batch path
steps thousands of robots at once on numpy arrays. Numpy on scalars costs ~90 us a step, so the
same source must run on ``math`` for floats and on ``numpy`` for arrays. Law code asks
``namespace_for(x)`` once per call and uses only the functions defined here, or (the unified
law, ``make_step``) binds them once into a closure, which numba can also compile.
"""

from __future__ import annotations

import ast
import inspect
import math
import textwrap
from collections.abc import Callable
from typing import Any

import numpy as np


class FloatMath:
    """Scalar functions on Python floats (the real-time path)."""

    is_array = False
    pi = math.pi
    sin = staticmethod(math.sin)
    cos = staticmethod(math.cos)
    tanh = staticmethod(math.tanh)
    sqrt = staticmethod(math.sqrt)
    exp = staticmethod(math.exp)
    atan2 = staticmethod(math.atan2)
    floor = staticmethod(math.floor)
    isfinite = staticmethod(math.isfinite)

    @staticmethod
    def abs(x: float) -> float:
        return x if x >= 0.0 else -x

    @staticmethod
    def sign(x: float) -> float:
        """Signum with sign(0) = 0, as in (10)."""
        return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)

    @staticmethod
    def where(cond: bool, a: float, b: float) -> float:
        return a if cond else b

    @staticmethod
    def clip(x: float, lo: float, hi: float) -> float:
        return lo if x < lo else (hi if x > hi else x)

    @staticmethod
    def minimum(a: float, b: float) -> float:
        return a if a < b else b

    @staticmethod
    def maximum(a: float, b: float) -> float:
        return a if a > b else b

    @staticmethod
    def full_like(x: float, value: float) -> float:
        return float(value)


class ArrayMath:
    """The same functions on numpy arrays (the batch path)."""

    is_array = True
    pi = np.pi
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    tanh = staticmethod(np.tanh)
    sqrt = staticmethod(np.sqrt)
    exp = staticmethod(np.exp)
    atan2 = staticmethod(np.arctan2)
    floor = staticmethod(np.floor)
    isfinite = staticmethod(np.isfinite)
    abs = staticmethod(np.abs)
    sign = staticmethod(np.sign)
    where = staticmethod(np.where)
    clip = staticmethod(np.clip)
    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)

    @staticmethod
    def full_like(x: Any, value: float) -> np.ndarray:
        return np.full(np.shape(x), float(value))


FLOAT_MATH = FloatMath()
ARRAY_MATH = ArrayMath()


def namespace_for(*values: Any) -> FloatMath | ArrayMath:
    """``ARRAY_MATH`` if any value is a numpy array, else ``FLOAT_MATH``."""
    for value in values:
        if isinstance(value, np.ndarray):
            return ARRAY_MATH
    return FLOAT_MATH


# --- the float path without helper calls ---------------------------------------------------
# Each call of FloatMath.sign or clip from Python costs ~50-80 ns, a tenth of the unified law's
# update. The law's one definition (a factory ``make_step(ns)`` returning a closure) is kept;
# its float instance is compiled from that same source with these two helpers written inline,
# as numba inlines them on the compiled path. Each argument is evaluated once (a walrus
# temporary) and the expressions are FloatMath's own, so the result is bit for bit the same.

_INLINE = {
    # name -> (number of arguments, the inline form: {0} the temporary, {1}, {2} the bounds)
    "sign": (1, "(1.0 if ({0} := {a0}) > 0.0 else (-1.0 if {0} < 0.0 else 0.0))"),
    "clip": (3, "({a1} if ({0} := {a0}) < {a1} else ({a2} if {0} > {a2} else {0}))"),
}


def _pure(node: ast.expr) -> bool:
    """A bound that may be evaluated twice: a name, a number or its negation."""
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        node = node.operand
    return isinstance(node, ast.Name | ast.Constant)


class _InlineHelpers(ast.NodeTransformer):
    def __init__(self) -> None:
        self.count = 0

    def visit_Call(self, node: ast.Call) -> ast.AST:
        self.generic_visit(node)
        spec = _INLINE.get(node.func.id) if isinstance(node.func, ast.Name) else None
        if spec is None or len(node.args) != spec[0] or node.keywords:
            return node
        if not all(_pure(b) for b in node.args[1:]):
            return node
        temp = f"_inline{self.count}"
        self.count += 1
        parts = {f"a{i}": ast.unparse(a) for i, a in enumerate(node.args)}
        return ast.parse(spec[1].format(temp, **parts), mode="eval").body


def inline_float_helpers(factory: Callable[[Any], Any], ns: FloatMath) -> Callable[..., Any]:
    """``factory(ns)`` compiled from ``factory``'s own source with the calls of ``sign`` and
    ``clip`` in it written inline (see the comment above). ``factory`` must be a module-level
    function whose body binds those names from ``ns``; where its source cannot be read (a
    frozen or source-less install) the plain ``factory(ns)`` is returned."""
    try:
        source = textwrap.dedent(inspect.getsource(factory))
    except (OSError, TypeError):
        return factory(ns)
    tree = ast.parse(source)
    transformer = _InlineHelpers()
    tree = ast.fix_missing_locations(transformer.visit(tree))
    if transformer.count == 0:
        return factory(ns)
    namespace: dict[str, Any] = dict(factory.__globals__)
    exec(compile(tree, inspect.getsourcefile(factory) or "<inlined>", "exec"), namespace)
    return namespace[factory.__name__](ns)

"""A small math namespace so every law and the plant are written once.

The real-time path steps one robot on plain Python floats (about 2 us a step); the batch path
steps thousands of robots at once on numpy arrays. Numpy on scalars costs ~90 us a step, so the
same source must run on ``math`` for floats and on ``numpy`` for arrays. Law code asks
``namespace_for(x)`` once per call and uses only the functions defined here, or (the unified
law, ``make_step``) binds them once into a closure, which numba can also compile.
"""

from __future__ import annotations

import math
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

"""How every page writes a time: one function (seconds in, milliseconds out), below every
module that writes one (the verdict's reasons, the report, the comparison, the fleet's table)."""

from __future__ import annotations

import math
from typing import Any


def ms(seconds: float, digits: int = 3, unit: str = " ms") -> str:
    """``seconds`` as milliseconds with ``digits`` decimals and ``unit`` after: 0.0123 ->
    "12.300 ms"."""
    return f"{seconds * 1e3:.{digits}f}{unit}"


def ms_or(seconds: Any, missing: str, digits: int = 3, unit: str = " ms") -> str:
    """:func:`ms` of a finite number, else ``missing`` (None, a NaN, not a number)."""
    number = isinstance(seconds, int | float) and not isinstance(seconds, bool)
    return ms(seconds, digits, unit) if number and math.isfinite(seconds) else missing

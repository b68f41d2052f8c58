"""Validation of user-given parameters: each failure names the field, its value and the range."""

from __future__ import annotations

import math
from typing import Any

from .errors import ParameterError


def positive(name: str, v: Any, *, allow_zero: bool = False, upper: float | None = None
             ) -> float:
    """A finite real number > 0 (>= 0 with ``allow_zero``), at most ``upper``."""
    if isinstance(v, bool):
        raise ParameterError(name, v, "a number")
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ParameterError(name, v, "a number") from None
    lo_ok = x >= 0 if allow_zero else x > 0
    if not (math.isfinite(x) and lo_ok and (upper is None or x <= upper)):
        rng = (">= 0" if allow_zero else "> 0") + (f" and <= {upper:g}" if upper else "")
        raise ParameterError(name, v, rng + " (finite)")
    return x


def integer(name: str, v: Any, lo: int, hi: int) -> int:
    if (isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)
            or int(v) != v or not lo <= v <= hi):
        raise ParameterError(name, v, f"an integer from {lo} to {hi}")
    return int(v)


def choice(name: str, v: Any, allowed: tuple[str, ...]) -> str:
    if v not in allowed:
        raise ParameterError(name, v, " or ".join(repr(a) for a in allowed))
    return v

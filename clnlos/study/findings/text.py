"""The wording of the study's findings where a number is a limit of what was tried, or the
data cannot decide (pure Python, no OpenCL; issue 51).

A threshold found on a sweep (the smallest legible letter, the exposure needed) that equals
the smallest value tried is an upper bound, not a threshold: the true one may lie below.
Said as ``<= 0.001 s (the smallest tried)``; one never reached as ``> 1 s (not reached: the
largest tried)``.

A verdict "geometry dominates" (or "material") compares identification accuracies, each
from a few glyphs and so with a wide Wilson interval (2 glyphs: 0.09-0.91). It is given only
where the data separate the accuracies: the geometry's effect is established where, for some
material, two values of the swept variable give Wilson intervals that do not overlap; the
material's where, at some value, two materials' intervals do not overlap. Neither or both
established alike: no verdict unless both are and the effects differ."""

from __future__ import annotations

from collections.abc import Iterable, Sequence


def limit_text(value: float | None, tried: Iterable[float], unit: str = "") -> str:
    """A threshold found on a sweep of the values ``tried`` (where smaller is harder to
    reach: an exposure, a letter height): ``value`` with its unit inside the sweep,
    ``<= value (the smallest tried)`` at its smallest value, and ``> largest (not reached:
    the largest tried)`` when ``value`` is None (never reached)."""
    values = sorted(float(v) for v in tried)
    if not values:
        raise ValueError("tried: no values")
    u = f" {unit}" if unit else ""
    if value is None:
        return f"> {values[-1]:g}{u} (not reached: the largest tried)"
    if float(value) <= values[0]:
        return f"<= {float(value):g}{u} (the smallest tried)"
    return f"{float(value):g}{u}"


def intervals_overlap(a: Sequence[float], b: Sequence[float]) -> bool:
    """Whether the intervals [a0, a1] and [b0, b1] share a point."""
    return float(a[0]) <= float(b[1]) and float(b[0]) <= float(a[1])


def any_separated(intervals: Iterable[Sequence[float]]) -> bool:
    """Whether two of the intervals do not overlap (the highest lower bound lies above the
    lowest upper bound)."""
    iv = [(float(lo), float(hi)) for lo, hi in intervals]
    return len(iv) > 1 and max(lo for lo, _ in iv) > min(hi for _, hi in iv)


def dominance_verdict(rows: Iterable[dict], geometry_effect: float,
                      material_effect: float) -> str | None:
    """"geometry", "material" or None (no verdict) for one swept variable. ``rows``: its
    sweep points, each ``{"material", "value", "identification": {"ci": [lo, hi]}}`` (the
    Wilson interval); ``geometry_effect`` and ``material_effect``: the mean identification
    range over the variable per material and the mean spread between materials per value
    (what the study compares). A side whose intervals never separate cannot dominate; where
    both separate, the larger effect does."""
    rows = list(rows)
    by_material: dict = {}
    by_value: dict = {}
    for r in rows:
        ci = r["identification"]["ci"]
        by_material.setdefault(r["material"], []).append(ci)
        by_value.setdefault(r["value"], []).append(ci)
    geometry = any(any_separated(v) for v in by_material.values())
    material = any(any_separated(v) for v in by_value.values())
    if geometry and material:
        if geometry_effect == material_effect:
            return None
        return "geometry" if geometry_effect > material_effect else "material"
    if geometry:
        return "geometry"
    if material:
        return "material"
    return None


def verdict_text(verdict: str | None) -> str:
    """The findings' words for :func:`dominance_verdict`."""
    if verdict is None:
        return "no verdict: the Wilson intervals overlap"
    return f"{verdict} dominates"

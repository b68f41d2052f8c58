"""The hidden patterns of the legibility judge's twins: the stroke font's capital letters and
the charts real NLOS targets are (pure numpy, no OpenCL).

A pattern is named and centred on its centre. Letters fill the stroke font's glyph box (0.6
x 1 heights ``height_m``); a chart fills a square of side CHART_SCALE heights (real charts
fill the scan more than a letter does, and coarser than the letters' strokes they are not
resolved at the twins' grid) and is a union of axis-aligned rectangles on the target plane,
given in units of its side as (x centre, y centre, width, height):

* ``bars_v`` / ``bars_h``: CHART_BARS bars of width 1/(2 CHART_BARS - 1), one bar width
  apart (a resolution chart's bar group, upright or lying);
* ``dots_3x3`` / ``dots_2x2``: a grid of square dots of side 1/(2 n - 1), one side apart (a
  dot chart).

The same rectangles make the scene's objects (:func:`pattern_objects`) and the true mask
(:func:`pattern_mask`), so the label's template is what was simulated.
"""

from __future__ import annotations

import numpy as np

from clnlos.forward.geometry import letters_mask

CHART_BARS = 3
CHART_SCALE = 1.4   # a chart's side over the letter height
TWIN_LETTERS = ("E", "F", "H", "L", "P", "T", "U", "X", "S", "Z")
TWIN_CHARTS = ("bars_v", "bars_h", "dots_3x3", "dots_2x2")
TWIN_PATTERNS = TWIN_LETTERS + TWIN_CHARTS


def _grid(n: int) -> list[float]:
    """Centres of n cells of side 1/(2n - 1), one side apart, spanning [-1/2, 1/2]."""
    side = 1.0 / (2 * n - 1)
    return [-0.5 + side / 2 + 2 * side * k for k in range(n)]


def chart_rectangles(name: str) -> list[tuple[float, float, float, float]]:
    """(x, y, width, height) of the chart's rectangles, in units of its side (CHART_SCALE
    letter heights)."""
    if name in ("bars_v", "bars_h"):
        w = 1.0 / (2 * CHART_BARS - 1)
        bars = [(x, 0.0, w, 1.0) for x in _grid(CHART_BARS)]
        return bars if name == "bars_v" else [(y, x, h, w) for x, y, w, h in bars]
    if name.startswith("dots_"):
        n = int(name.split("x")[-1])
        side = 1.0 / (2 * n - 1)
        return [(x, y, side, side) for y in _grid(n) for x in _grid(n)]
    raise ValueError(f"{name}: not a chart ({', '.join(TWIN_CHARTS)})")


def is_chart(name: str) -> bool:
    return name in TWIN_CHARTS


def pattern_mask(name: str, height_m: float, stroke_m: float, xy: np.ndarray) -> np.ndarray:
    """True where local points xy (N, 2) (m, from the pattern's centre) lie on the pattern."""
    xy = np.asarray(xy, float)
    if not is_chart(name):
        return letters_mask(name, height_m, stroke_m, xy)
    inside = np.zeros(len(xy), bool)
    side = CHART_SCALE * height_m
    for x, y, w, h in chart_rectangles(name):
        inside |= ((np.abs(xy[:, 0] - x * side) <= w * side / 2)
                   & (np.abs(xy[:, 1] - y * side) <= h * side / 2))
    return inside


def pattern_objects(name: str, height_m: float, stroke_m: float, centre_m,
                    material, albedo: float = 1.0) -> list[dict]:
    """The scene's [[objects]] tables of the pattern centred at ``centre_m`` (x, y, z)."""
    cx, cy, z = (float(v) for v in centre_m)
    if not is_chart(name):
        return [{"shape": "letters", "text": name, "height_m": height_m, "stroke_m": stroke_m,
                 "translate_m": [cx, cy, z], "material": material, "albedo": albedo}]
    side = CHART_SCALE * height_m
    return [{"shape": "rectangle", "size_m": [w * side, h * side],
             "translate_m": [cx + x * side, cy + y * side, z], "material": material,
             "albedo": albedo} for x, y, w, h in chart_rectangles(name)]

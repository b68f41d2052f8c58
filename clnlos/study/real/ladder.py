"""Nested thinning ladders refined at their crossing: how far a capture's photons can be
thinned before a score falls below a level.

A series thins the counts binomially down ``ladder`` (nested: every photon of a fainter rung
is one of the brighter rung's, the exact model of a shorter exposure, :mod:`clnlos.study.real.
thinning`), stopping at the first rung whose score falls below the level; rungs are then
inserted at the geometric mean of the last kept and the first lost fraction, nested between
them (each photon of the kept rung not in the lost one kept with probability
(f - f_lost) / (f_kept - f_lost)), until the two are within ``ratio`` of each other, and the
crossing is interpolated in log photons between them. A series that never falls bounds the
fraction needed from above (``status`` "at most").
"""

from __future__ import annotations

import math

import numpy as np

LADDER = (1.0, 0.3, 0.1, 0.03, 0.01, 0.003, 0.001, 0.0003)
RATIO = 1.5            # the crossing bracketed within this ratio of photons
MAX_INSERTS = 8        # rungs inserted per series at most
BRACKETED, AT_MOST, NOT_KEPT = "bracketed", "at most", "not kept"


def _nested_between(kept: np.ndarray, lost: np.ndarray, f_kept: float, f_lost: float,
                    f: float, rng) -> np.ndarray:
    """The rung at fraction ``f`` between two nested rungs: the lost rung's photons and each
    other photon of the kept rung with probability (f - f_lost) / (f_kept - f_lost)."""
    extra = np.rint(kept).astype(np.int64) - np.rint(lost).astype(np.int64)
    q = (f - f_lost) / (f_kept - f_lost)
    return (lost + rng.binomial(np.maximum(extra, 0), q)).astype(np.float32)


def series_crossing(score, counts: np.ndarray, seed: int, *, level: float, ladder=LADDER,
                    ratio: float = RATIO, full_score: float = 1.0) -> dict:
    """One nested series (the module docstring): ``score(counts)`` of each rung tried
    (``tried``: [(fraction, score)], brightest first), the bracket [``lost``, ``kept``]
    around where it first falls below ``level`` and the ``crossing`` fraction
    (interpolated in log photons); or, where it never falls, the last rung (``status``
    "at most": an upper bound of the fraction needed); ``full_score`` is the score of all the
    counts (1 against their own image): below the level, the series is "not kept"."""
    rng = np.random.default_rng(seed)
    tried = {1.0: float(full_score)}
    if full_score < level:
        return {"status": NOT_KEPT, "kept": None, "lost": 1.0, "crossing": None,
                "tried": [(1.0, float(full_score))]}
    rungs = {1.0: np.rint(counts).astype(np.float32)}
    f_kept, f_lost = 1.0, None
    for f in ladder[1:]:
        rungs[f] = rng.binomial(np.rint(rungs[f_kept]).astype(np.int64),
                                f / f_kept).astype(np.float32)
        tried[f] = score(rungs[f])
        if tried[f] < level:
            f_lost = f
            break
        f_kept = f
    if f_lost is None:
        return {"status": AT_MOST, "kept": f_kept, "lost": None, "crossing": f_kept,
                "tried": sorted(tried.items(), reverse=True)}
    for _ in range(MAX_INSERTS):
        if f_kept / f_lost <= ratio:
            break
        f = math.sqrt(f_kept * f_lost)
        rungs[f] = _nested_between(rungs[f_kept], rungs[f_lost], f_kept, f_lost, f, rng)
        tried[f] = score(rungs[f])
        if tried[f] >= level:
            f_kept = f
        else:
            f_lost = f
    s_k, s_l = tried[f_kept], tried[f_lost]
    w = (s_k - level) / (s_k - s_l) if s_k > s_l else 0.0
    crossing = math.exp(math.log(f_kept) + w * (math.log(f_lost) - math.log(f_kept)))
    return {"status": BRACKETED, "kept": f_kept, "lost": f_lost, "crossing": crossing,
            "tried": sorted(tried.items(), reverse=True)}



def series_summary(series: list[dict], photons: float) -> dict:
    """The photons needed of several series: the median crossing (``status`` of the median
    series: "bracketed" or "at most"; "not kept" where a series is), and the ``interval``
    from the smallest lost to the largest kept rung of any series (None at an open end):
    every bracket and the seeds' spread."""
    if any(s["status"] == NOT_KEPT for s in series):
        return {"photons_needed": None, "status": NOT_KEPT, "interval": None}
    crossings = [s["crossing"] for s in series]
    k_med = int(np.argsort(crossings)[len(crossings) // 2])
    lo = min((s["lost"] for s in series if s["lost"] is not None), default=None)
    hi = max(s["kept"] for s in series)
    return {"photons_needed": float(np.median(crossings)) * photons,
            "status": series[k_med]["status"],
            "interval": [None if lo is None else lo * photons, hi * photons]}


def bounded_ratio(num: dict, den: dict) -> tuple[float | None, str | None]:
    """num / den of two photons-needed summaries, with ``"<="`` where the numerator is an
    upper bound ("at most"), ``">="`` where the denominator is, ``"unknown"`` where both
    are: a bound stays a bound; (None, None) where either is not kept."""
    if num["photons_needed"] is None or den["photons_needed"] is None:
        return None, None
    r = num["photons_needed"] / den["photons_needed"]
    a, b = num["status"] == AT_MOST, den["status"] == AT_MOST
    return r, ("unknown" if a and b else "<=" if a else ">=" if b else None)

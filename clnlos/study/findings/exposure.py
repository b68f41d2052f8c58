"""The answer a user plans with (results.json ``plan``): per material x target x inversion, the
photons per capture and the exposure per scan point needed to read the target, from the
curve of the share of legible realisations against exposure.

The curve. Each swept exposure E_j holds n_j reconstructions (letters of the target x noise
realisations), k_j of them legible (:mod:`clnlos.study.samples.identify`); the share
p_j = k_j / n_j with its Wilson 95% interval. The shares are made non-decreasing in E by the
pool-adjacent-violators fit q_j (a longer exposure never reads worse; the weights are n_j).

The exposure needed: the exposure where q first reaches the study's ``legible_fraction`` L
(0.9: legible in 90% of realisations), interpolated linearly in log E between the last rung
below and the first at or above L (the photons likewise in log photons); its interval runs
from the first rung whose Wilson interval reaches L (fewer photons may still read in 90% of
captures: n realisations cannot tell) to the first rung where q reaches L, and always holds
the bracket. Where no rung reaches L the row is "beyond the sweep" (its lower bound the
largest exposure tried); where the smallest already does, "at most" the smallest (an upper
bound). No number beyond the sweep is made up.

The bracket is refined (:func:`refinement`): rungs are added inside it, evenly in log
exposure, until its ends are within the study's ``refine_ratio`` (1.5) of each other.

Curtailed realisations (:func:`rungs_to_render`): every rung gets its first realisation;
then, one at a time in the order of their realisation index, only the two lowest rungs of a
curve that are neither stopped nor complete below L, until the lowest of them is complete
and reads (the curve is decided); then every rung above it that read a failure is completed,
so the fit pools full rungs where the data are not monotone. A rung stops once even its best
completion rules L out (the Wilson interval of n - f of n ends below L: f = 2 of 4 at L =
0.9), so a stopped rung says of the interval what the whole rung would, whatever the order
its realisations came in; the rungs above the decided one that read every time keep what
they have (their first realisation, weight 1 in the fit). A point holds the realisations
rendered (k of n' <= n, the Wilson interval of those): the rung that decides the answer
holds all n. The interpolated exposure uses the share of the rung below the bracket as
rendered (a stopped rung's share, biased low by its stop, moves the estimate within the
bracket).
"""

from __future__ import annotations

import math

import numpy as np

from clnlos.study.score.legibility import wilson_interval

MAX_REFINEMENTS = 4   # rounds of refinement at most
RUNGS_PER_ROUND = 2   # rungs added to one bracket in one round at most
BRACKETED, BEYOND, BELOW = "bracketed", "beyond the sweep", "at most the smallest exposure"


def curve_key(meta: dict) -> tuple:
    """What one exposure curve is of: its sweep, the other swept values, the target, the
    material, the method and the reflectance assumed."""
    at = tuple(sorted(meta.get("at", {}).items()))
    return (meta["sweep"], at, meta["target"], meta["material"], meta["method"],
            meta["inversion"])


def rung_key(meta: dict) -> tuple | None:
    """The exposure rung an entry is a realisation of (its curve and exposure); None for an
    entry on no exposure curve."""
    if meta.get("variable") != "exposure_s" or "sweep" not in meta:
        return None
    return curve_key(meta), float(meta["value"])


def allowed_failures(planned: int, level: float) -> int:
    """Failures a rung of ``planned`` realisations can hold and still reach ``level``."""
    return planned - math.ceil(level * planned - 1e-9)


def rung_stopped(failures: int, planned: int, level: float) -> bool:
    """A rung that rules ``level`` out whatever its other realisations read: the Wilson
    interval of its best completion (planned - failures legible of planned) ends below it.
    So a rung stopped early says of the exposure needed's interval what the whole rung
    would, whatever the order its realisations came in."""
    return wilson_interval(planned - failures, planned)[1] < level


def rungs_to_render(state: dict, level: float) -> list:
    """The rungs whose next realisation is rendered (the module docstring): ``state`` {rung
    key: (rendered, failures, planned)}. Every rung without one; else, per curve, of its
    rungs neither stopped (:func:`rung_stopped`) nor complete below the level, the two
    lowest where incomplete; once the lowest of them is complete (it reads: the curve is
    decided), every rung above it that read a failure, to its end (the fit pools them)."""
    fresh = [key for key, (m, _, _) in state.items() if m == 0]
    if fresh:
        return fresh
    curves: dict = {}
    for key in sorted(state, key=lambda k: k[1]):
        curves.setdefault(key[0], []).append(key)
    out = []
    for keys in curves.values():
        incomplete = [k for k in keys if state[k][0] < state[k][2]]
        live = [k for k in keys if not rung_stopped(state[k][1], state[k][2], level) and not (
            state[k][1] > allowed_failures(state[k][2], level) and k not in incomplete)]
        if not live:
            continue
        if live[0] in incomplete:
            out += [k for k in live[:2] if k in incomplete]
        else:
            out += [k for k in incomplete if k[1] > live[0][1] and state[k][1] > 0]
    return out


def exposure_curves(plan, results, study) -> dict[tuple, list[dict]]:
    """{curve_key: points in exposure order}: per rung its exposure (s, per scan point), the
    mean photons per capture, n, k legible, the share and its Wilson interval."""
    groups: dict = {}
    for (meta, _), r in zip(plan, results, strict=True):
        if meta.get("variable") != "exposure_s" or "sweep" not in meta:
            continue
        pts = groups.setdefault(curve_key(meta), {})
        pts.setdefault(meta["value"], []).append(r)
    out = {}
    for key, pts in groups.items():
        rows = []
        for e in sorted(pts):
            rs = pts[e]
            k = sum(bool(r["identified"]) for r in rs)
            rows.append({"exposure_s": float(e), "photons": float(np.mean([r["counts"]
                                                                         for r in rs])),
                         "n": len(rs), "k": int(k), "fraction": k / len(rs),
                         "ci": wilson_interval(k, len(rs))})
        out[key] = rows
    return out


def isotonic(values, weights) -> list[float]:
    """The non-decreasing least-squares fit of ``values`` (weights ``weights``): pool
    adjacent violators."""
    blocks = []  # [mean, weight, count]
    for v, w in zip(values, weights, strict=True):
        blocks.append([float(v), float(w), 1])
        while len(blocks) > 1 and blocks[-2][0] > blocks[-1][0]:
            v2, w2, c2 = blocks.pop()
            v1, w1, c1 = blocks.pop()
            blocks.append([(v1 * w1 + v2 * w2) / (w1 + w2), w1 + w2, c1 + c2])
    out = []
    for v, _, c in blocks:
        out += [v] * c
    return out


def _log_interp(x0: float, x1: float, w: float) -> float:
    return float(math.exp(math.log(x0) + w * (math.log(x1) - math.log(x0))))


def exposure_needed(points: list[dict], level: float) -> dict:
    """The exposure and photons needed of one curve (the module docstring): ``status``,
    ``exposure_needed_s`` and ``photons_needed`` (None unless bracketed), their intervals
    (an open end None), the bracket, the share at the rung that reads and its interval."""
    q = isotonic([p["fraction"] for p in points], [p["n"] for p in points])
    j = next((i for i, v in enumerate(q) if v >= level), None)
    first_possible = next((i for i, p in enumerate(points) if p["ci"][1] >= level), None)
    out = {"fit": q, "level": level}
    if j is None:
        last = points[-1]
        lo = points[first_possible] if first_possible is not None else last
        return {**out, "status": BEYOND, "exposure_needed_s": None, "photons_needed": None,
                "exposure_needed_interval_s": [lo["exposure_s"], None],
                "photons_needed_interval": [lo["photons"], None],
                "bracket_s": [last["exposure_s"], None], "legible_fraction": None,
                "legible_interval": None}
    hit = points[j]
    lo_i = min(j - 1 if j > 0 else j, first_possible if first_possible is not None else j)
    base = {**out, "legible_fraction": hit["fraction"], "legible_interval": hit["ci"],
            "n": hit["n"], "k": hit["k"]}
    if j == 0:
        return {**base, "status": BELOW, "exposure_needed_s": None, "photons_needed": None,
                "exposure_needed_interval_s": [None, hit["exposure_s"]],
                "photons_needed_interval": [None, hit["photons"]],
                "bracket_s": [None, hit["exposure_s"]]}
    prev = points[j - 1]
    w = (level - q[j - 1]) / (q[j] - q[j - 1]) if q[j] > q[j - 1] else 1.0
    return {**base, "status": BRACKETED,
            "exposure_needed_s": _log_interp(prev["exposure_s"], hit["exposure_s"], w),
            "photons_needed": _log_interp(prev["photons"], hit["photons"], w),
            "exposure_needed_interval_s": [points[lo_i]["exposure_s"], hit["exposure_s"]],
            "photons_needed_interval": [points[lo_i]["photons"], hit["photons"]],
            "bracket_s": [prev["exposure_s"], hit["exposure_s"]]}


def refinement(curves: dict, level: float, ratio: float) -> dict[tuple, list[float]]:
    """{curve: the exposures to add}: where a bracket's ends are more than ``ratio`` apart,
    rungs spaced evenly in log exposure inside it -- as many as bring it within ``ratio``,
    at most two a round (a decade within 1.5x in two rounds, three rungs, as bisection);
    none where ``ratio`` is 0."""
    if not ratio:
        return {}
    out = {}
    for key, pts in curves.items():
        a = exposure_needed(pts, level)
        lo, hi = a["bracket_s"]
        if a["status"] == BRACKETED and hi / lo > ratio:
            n = min(RUNGS_PER_ROUND, math.ceil(math.log(hi / lo) / math.log(ratio)) - 1)
            out[key] = [lo * (hi / lo) ** (k / (n + 1)) for k in range(1, n + 1)]
    return out


def plan_rows(curves: dict, study) -> list[dict]:
    """results.json ``plan``: one row per curve (material, target, method, reflectance, the
    other swept values ``at``), the exposure and photons needed with their intervals, the
    curve, and ``best`` on the row of each material x target x ``at`` that needs the least
    (bounds compared as bounds: a bracketed need beats one beyond the sweep)."""
    rows = []
    for key, pts in curves.items():
        sweep, at, target, material, method, refl = key
        a = exposure_needed(pts, study.legible_fraction)
        rows.append({"material": material, "target": target, "method": method,
                     "reflectance": refl, "at": dict(at), "sweep": sweep,
                     **{k: v for k, v in a.items() if k != "fit"},
                     "curve": [{**p, "fit": f} for p, f in zip(pts, a["fit"], strict=True)]})
    for group in {(r["material"], r["target"], tuple(sorted(r["at"].items()))) for r in rows}:
        mine = [r for r in rows if (r["material"], r["target"],
                                    tuple(sorted(r["at"].items()))) == group]
        best = min(mine, key=need_order)
        for r in mine:
            r["best"] = r is best and best["status"] != BEYOND
    order = {m.name: i for i, m in enumerate(study.materials)}
    rows.sort(key=lambda r: (order.get(r["material"], 0), r["target"], r["sweep"],
                             sorted(r["at"].items()), r["method"], r["reflectance"]))
    return rows


def need_order(row: dict) -> tuple:
    """Sorts needs: "at most" the smallest first, then bracketed by value, then beyond the
    sweep by its lower bound."""
    if row["status"] == BELOW:
        return (0, row["exposure_needed_interval_s"][1])
    if row["status"] == BRACKETED:
        return (1, row["exposure_needed_s"])
    return (2, row["exposure_needed_interval_s"][0])


def smallest_letters(plan, results, study) -> list[dict]:
    """results.json ``smallest_legible_letter``: per height sweep's curve (target, material,
    method, reflectance, exposure) the smallest letter height whose share of legible
    reconstructions reaches the study's level and stays there at every larger height (None
    where none does), beside the heights tried."""
    groups: dict = {}
    for (meta, s), r in zip(plan, results, strict=True):
        if "sweep" not in meta:
            continue
        sw = study.sweeps[meta["sweep"]]
        if "letter_height_m" not in sw.variables:
            continue
        e = s["exposure_s"]
        key = (meta["target"], meta["material"], meta["method"], meta["inversion"], e)
        h = (meta["value"] if meta["variable"] == "letter_height_m"
             else meta["at"]["letter_height_m"])
        groups.setdefault(key, {}).setdefault(h, []).append(bool(r["identified"]))
    out = []
    for (target, material, method, refl, e), by_h in groups.items():
        hs = sorted(by_h)
        q = isotonic([np.mean(by_h[h]) for h in hs], [len(by_h[h]) for h in hs])
        ok = next((h for h, v in zip(hs, q, strict=True) if v >= study.legible_fraction),
                  None)
        out.append({"target": target, "material": material, "method": method,
                    "reflectance": refl, "exposure_s": e, "letter_height_m": ok,
                    "heights_m": hs, "fractions": [float(np.mean(by_h[h])) for h in hs]})
    return out

"""The material table under both transports: does the seed's confocal approximation (Eq. 9)
change the study's ranking of materials? (issue 27, item 7)

The study simulates every sample with the confocal transport (light leaves and re-enters
the slab's hidden face at one point, the BRDF read on its retro slice f(w, w)). This stage
renders the study's main glyphs at the legible geometry a second time with Eq. 8 in full
(``[transport] model = "bistatic"``, :mod:`clnlos.forward.bistatic`, ``face_rings`` x
``face_angles`` face samples) -- the same scenes, the same noise seeds, the same
reconstruction and the same identification rule -- and tabulates per material:
identification accuracy (Wilson 95% interval), the mean NCC margin of the true glyph over
the best other one (> 0: identified; a continuous legibility score), the IoU and the
photon counts under each transport, the rank of each material under each (by accuracy,
ties broken by the margin), and Spearman's and Kendall's rank correlations between the
two (of the accuracies and of the margins). A material "moves" when its rank changes.

Samples go through :func:`clnlos.study.samples.identify.render_plan` and the study's cache: the
confocal side is the study's own main samples (same cache entries); a bistatic sample is
the same sample dict with a ``transport`` table (its own cache key).

Cost (the forward model of one glyph at the study's grid, 32 x 32 points, 48 ps bins, on
2 CPU cores shared with other jobs; tools/results/study_transport_faces.csv): confocal
0.6-1.6 s, bistatic 2 x 4 face samples 3.7-19 s, 3 x 6 16-114 s, 4 x 8 123-225 s; the
reconstruction adds some 5-10 s to each sample. Default 2 x 4: within 5% (relative L2) of
4 x 8 for the sharpest lobe, 1% for the others measured. It runs with
``clnlos study --transport both``; the committed results are
tools/results/study_transport.{csv,json} (``tools/study_transport.py``).
"""

from __future__ import annotations

import math

import numpy as np

from clnlos.study.score.legibility import identification_summary

TRANSPORTS = ("confocal", "bistatic")


def rank_of(accuracy, margin) -> np.ndarray:
    """Rank (1 = most legible) of each material: by identification accuracy, ties broken
    by the mean NCC margin."""
    order = sorted(range(len(accuracy)), key=lambda i: (-accuracy[i], -margin[i]))
    rank = np.empty(len(order), int)
    rank[order] = np.arange(1, len(order) + 1)
    return rank


def average_ranks(x) -> np.ndarray:
    """Ranks 1..n of ``x``, tied values sharing the mean of their ranks."""
    x = np.asarray(x, float)
    order = np.argsort(x, kind="stable")
    ranks = np.empty(x.size)
    ranks[order] = np.arange(1, x.size + 1)
    for v in np.unique(x):
        tied = x == v
        ranks[tied] = ranks[tied].mean()
    return ranks


def spearman_rho(a, b) -> float:
    """Spearman's rho: Pearson's correlation of the average ranks."""
    ra, rb = average_ranks(a) - (len(a) + 1) / 2, average_ranks(b) - (len(b) + 1) / 2
    return float(np.sum(ra * rb) / math.sqrt(np.sum(ra**2) * np.sum(rb**2)))


def kendall_tau_b(a, b) -> float:
    """Kendall's tau-b = (P - Q) / sqrt((P + Q + T) (P + Q + U)): P concordant and Q
    discordant pairs, T pairs tied in ``a`` only, U in ``b`` only."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    da = np.sign(a[:, None] - a[None, :])[np.triu_indices(a.size, 1)]
    db = np.sign(b[:, None] - b[None, :])[np.triu_indices(b.size, 1)]
    s = da * db
    p, q = np.sum(s > 0), np.sum(s < 0)
    t, u = np.sum((da == 0) & (db != 0)), np.sum((db == 0) & (da != 0))
    return float((p - q) / math.sqrt((p + q + t) * (p + q + u)))


def _corr(a, b) -> dict:
    """Spearman's rho and Kendall's tau-b of a and b (None where one of them is constant)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return {"spearman": None, "kendall": None}
    return {"spearman": spearman_rho(a, b), "kendall": kendall_tau_b(a, b)}


def comparison_table(materials, plan, results, chance: float, table=None) -> dict:
    """The comparison from identified results
    (:func:`clnlos.study.samples.identify.identification_of` run on ``plan``): ``rows`` per
    material, ``correlation``, ``moved`` and ``statement``."""
    rows = []
    for m in materials:
        row = {"material": m, "brdf_class": None if table is None else table[m]["class"]}
        for tr in TRANSPORTS:
            rs = [r for (meta, _), r in zip(plan, results, strict=True)
                  if meta["set"] == "transport" and meta["material"] == m
                  and meta["transport"] == tr]
            ident = identification_summary([r["identified"] for r in rs], chance)
            row[tr] = {"identification": ident,
                       "margin": float(np.mean([r["true_margin"] for r in rs])),
                       "ncc_true": float(np.mean([r["ncc_true"] for r in rs])),
                       "iou": float(np.mean([r["iou"] for r in rs])),
                       "photon_counts": float(np.mean([r["counts"] for r in rs])),
                       "identified_as": [r["identified_as"] for r in rs], "n": len(rs)}
        row["counts_ratio"] = row["bistatic"]["photon_counts"] / row["confocal"][
            "photon_counts"]
        rows.append(row)
    for tr in TRANSPORTS:
        rk = rank_of([r[tr]["identification"]["accuracy"] for r in rows],
                     [r[tr]["margin"] for r in rows])
        for r, k in zip(rows, rk, strict=True):
            r[tr]["rank"] = int(k)
    for r in rows:
        r["rank_change"] = r["bistatic"]["rank"] - r["confocal"]["rank"]
        r["accuracy_change"] = (r["bistatic"]["identification"]["accuracy"]
                                - r["confocal"]["identification"]["accuracy"])
        r["margin_change"] = r["bistatic"]["margin"] - r["confocal"]["margin"]

    def col(tr, key):
        return [r[tr]["identification"]["accuracy"] if key == "accuracy" else r[tr][key]
                for r in rows]

    corr = {"rank": _corr(col("confocal", "rank"), col("bistatic", "rank")),
            "accuracy": _corr(col("confocal", "accuracy"), col("bistatic", "accuracy")),
            "margin": _corr(col("confocal", "margin"), col("bistatic", "margin"))}
    moved = [{"material": r["material"], "confocal_rank": r["confocal"]["rank"],
              "bistatic_rank": r["bistatic"]["rank"],
              "accuracy_change": r["accuracy_change"]} for r in rows if r["rank_change"]]
    return {"rows": rows, "correlation": corr, "moved": moved,
            "ranking_changes": bool(moved),
            "statement": comparison_statement(rows, corr, moved)}


def fmt_r(v) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def comparison_statement(rows, corr, moved) -> str:
    n = rows[0]["confocal"]["n"] if rows else 0
    acc_moves = [r for r in rows if r["accuracy_change"] != 0]
    big = max(rows, key=lambda r: abs(r["accuracy_change"]), default=None)
    s = (f"Under the bistatic transport (Eq. 8) the ranking of the {len(rows)} materials by "
         f"identification (ties by NCC margin; {n} reconstructions each) has Spearman "
         f"{fmt_r(corr['rank']['spearman'])} and Kendall {fmt_r(corr['rank']['kendall'])} with "
         f"the confocal one (Eq. 9); margins: Spearman {fmt_r(corr['margin']['spearman'])}. ")
    if not moved:
        return s + "No material changes rank: the seed's approximation does not change it."
    s += ("Rank changes: " + "; ".join(
        f"{m['material']} {m['confocal_rank']} -> {m['bistatic_rank']}" for m in moved) + ". ")
    if not acc_moves:
        return s + ("Identification is the same for every material: only the tie-breaking "
                    "NCC margins move, so the legibility classes do not change.")
    return s + (f"{len(acc_moves)} material(s) change identification accuracy, most "
                f"{big['material']} ({big['confocal']['identification']['accuracy']:.2f} -> "
                f"{big['bistatic']['identification']['accuracy']:.2f}).")


def csv_rows(comparison: dict) -> list[dict]:
    """Flat rows (one per material) for tools/results/study_transport.csv."""
    out = []
    for r in comparison["rows"]:
        row = {"material": r["material"], "brdf_class": r["brdf_class"]}
        for tr in TRANSPORTS:
            e = r[tr]
            row.update({f"{tr}_identification": e["identification"]["accuracy"],
                        f"{tr}_ci_lo": e["identification"]["ci"][0],
                        f"{tr}_ci_hi": e["identification"]["ci"][1],
                        f"{tr}_margin": e["margin"], f"{tr}_ncc_true": e["ncc_true"],
                        f"{tr}_iou": e["iou"], f"{tr}_rank": e["rank"]})
        row.update({"n": r["confocal"]["n"], "counts_ratio": r["counts_ratio"],
                    "rank_change": r["rank_change"]})
        out.append(row)
    return out





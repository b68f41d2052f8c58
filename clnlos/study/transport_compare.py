"""The material table under both transports: does the seed's confocal approximation (Eq. 9)
change the study's ranking of materials? (issue 27, item 7)

The study simulates every sample with the confocal transport (light leaves and re-enters
the slab's hidden face at one point, the BRDF read on its retro slice f(w, w)). This stage
renders the study's main glyphs at the legible geometry a second time with Eq. 8 in full
(``[transport] model = "bistatic"``, :mod:`clnlos.bistatic`, ``face_rings`` x
``face_angles`` face samples) -- the same scenes, the same noise seeds, the same
reconstruction and the same identification rule -- and tabulates per material:
identification accuracy (Wilson 95% interval), the mean NCC margin of the true glyph over
the best other one (> 0: identified; a continuous legibility score), the IoU and the
photon counts under each transport, the rank of each material under each (by accuracy,
ties broken by the margin), and Spearman's and Kendall's rank correlations between the
two (of the accuracies and of the margins). A material "moves" when its rank changes.

Samples go through :func:`clnlos.study.run.render_plan` and the study's cache: the
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

# face samples of the comparison (tools/results/study_transport_faces.csv)
# against 4 x 8 (tools/results/study_transport_faces.csv): 2 x 4 is 4.9% off in relative L2
# and 5% in total signal for quartz glass (the sharpest lobe, 0.75 deg; 3 x 6: 0.7%, 0.0%;
# the confocal model: 16.5%), 0.9% and 0.0% for the aluminium alloy (2.6 deg; confocal 11%);
# 3 x 6 costs 4-6x more
COMPARE_RINGS = 2
COMPARE_ANGLES = 4
TRANSPORTS = ("confocal", "bistatic")


def bistatic_table(rings: int = COMPARE_RINGS, angles: int = COMPARE_ANGLES) -> dict:
    """The ``transport`` table of a bistatic study sample (:func:`clnlos.study.dataset.
    scene_dict` passes it to the scene)."""
    return {"model": "bistatic", "face_rings": int(rings), "face_angles": int(angles)}


def comparison_plan(materials, opts) -> list[tuple[dict, dict]]:
    """(meta, sample) of every comparison sample: per material, glyph and noise realisation
    at the legible geometry, once confocal (the study's main sample itself) and once
    bistatic (the same sample with a ``transport`` table)."""
    from .run import LEGIBLE_GEOMETRY, _glyph_entries

    geo = opts.geometry(LEGIBLE_GEOMETRY)
    table = bistatic_table(opts.face_rings, opts.face_angles)
    plan = []
    for m in materials:
        for meta, s in _glyph_entries(opts, geo, m, opts.transport_glyphs or opts.glyphs,
                                      opts.seeds,
                                      {"set": "transport"}):
            plan.append(({**meta, "transport": "confocal"}, s))
            plan.append(({**meta, "transport": "bistatic"}, {**s, "transport": table}))
    return plan


def rank_of(accuracy, margin) -> np.ndarray:
    """Rank (1 = most legible) of each material: by identification accuracy, ties broken
    by the mean NCC margin."""
    order = sorted(range(len(accuracy)), key=lambda i: (-accuracy[i], -margin[i]))
    rank = np.empty(len(order), int)
    rank[order] = np.arange(1, len(order) + 1)
    return rank


def _corr(a, b) -> dict:
    """Spearman's rho and Kendall's tau-b of a and b (None where one of them is constant)."""
    from scipy import stats

    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return {"spearman": None, "kendall": None}
    rho = stats.spearmanr(a, b).statistic
    tau = stats.kendalltau(a, b).statistic
    return {"spearman": None if math.isnan(rho) else float(rho),
            "kendall": None if math.isnan(tau) else float(tau)}


def comparison_table(materials, plan, results, chance: float, table=None) -> dict:
    """The comparison from identified results (:func:`clnlos.study.run.identification_of`
    run on ``plan``): ``rows`` per material, ``correlation``, ``moved`` and ``statement``."""
    from .legibility import identification_summary

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


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def comparison_statement(rows, corr, moved) -> str:
    n = rows[0]["confocal"]["n"] if rows else 0
    acc_moves = [r for r in rows if r["accuracy_change"] != 0]
    big = max(rows, key=lambda r: abs(r["accuracy_change"]), default=None)
    s = (f"Under the bistatic transport (Eq. 8) the ranking of the {len(rows)} materials by "
         f"identification (ties by NCC margin; {n} reconstructions each) has Spearman "
         f"{_fmt(corr['rank']['spearman'])} and Kendall {_fmt(corr['rank']['kendall'])} with "
         f"the confocal one (Eq. 9); margins: Spearman {_fmt(corr['margin']['spearman'])}. ")
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


def fig_transport(comparison: dict, plan=None, results=None):
    """Identification per material under both transports (Wilson 95% intervals) and the
    NCC margins of one against the other; with samples, one glyph's MIP under each."""
    import matplotlib.pyplot as plt

    rows = comparison["rows"]
    names = [r["material"] for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(1, 2, figsize=(11.5, 4.4), constrained_layout=True)
    for k, tr in enumerate(TRANSPORTS):
        acc = np.array([r[tr]["identification"]["accuracy"] for r in rows])
        lo = np.array([r[tr]["identification"]["ci"][0] for r in rows])
        hi = np.array([r[tr]["identification"]["ci"][1] for r in rows])
        ax[0].bar(x + (k - 0.5) * 0.4, acc, 0.4,
                  yerr=[np.clip(acc - lo, 0, None), np.clip(hi - acc, 0, None)], capsize=2,
                  label=tr + (" (Eq. 9)" if tr == "confocal" else " (Eq. 8)"))
    if rows:
        chance = rows[0]["confocal"]["identification"]["chance"]
        ax[0].axhline(chance, color="gray", ls=":", label=f"chance {chance:.3f}")
    ax[0].set_xticks(x)
    ax[0].set_xticklabels([n if len(n) <= 18 else n[:17] + "." for n in names], rotation=55,
                          ha="right", fontsize=7)
    ax[0].set(ylabel="identification accuracy (95% Wilson interval)", ylim=(0, 1.05),
              title="legible geometry: identification under each transport")
    ax[0].legend(fontsize=7)
    mc = np.array([r["confocal"]["margin"] for r in rows])
    mb = np.array([r["bistatic"]["margin"] for r in rows])
    ax[1].scatter(mc, mb, s=22)
    for r, a, b in zip(rows, mc, mb, strict=True):
        ax[1].annotate(f"{r['material'][:14]} ({r['confocal']['rank']}->{r['bistatic']['rank']})",
                       (a, b), fontsize=6, xytext=(3, 2), textcoords="offset points")
    if rows:
        lim = [min(mc.min(), mb.min(), 0) - 0.02, max(mc.max(), mb.max()) + 0.02]
        ax[1].plot(lim, lim, color="gray", ls=":", label="equal")
        ax[1].axhline(0, color="k", lw=0.5)
        ax[1].axvline(0, color="k", lw=0.5)
        ax[1].set(xlim=lim, ylim=lim)
    c = comparison["correlation"]["rank"]
    ax[1].set(xlabel="mean NCC margin of the true glyph, confocal",
              ylabel="mean NCC margin, bistatic",
              title=f"margins (rank confocal->bistatic); Spearman {_fmt(c['spearman'])}, "
                    f"Kendall {_fmt(c['kendall'])}")
    ax[1].legend(fontsize=7)
    return fig


def comparison_html(comparison: dict, rings: int, angles: int) -> str:
    """The report's section body: how it was made, the table, the statement."""
    import html

    from .report import _table

    def cell(e):
        i = e["identification"]
        return f"{i['accuracy']:.2f} [{i['ci'][0]:.2f}, {i['ci'][1]:.2f}]"

    rows = [[html.escape(r["material"]), html.escape(str(r["brdf_class"] or "")),
             cell(r["confocal"]), cell(r["bistatic"]),
             f"{r['confocal']['margin']:+.3f}", f"{r['bistatic']['margin']:+.3f}",
             f"{r['confocal']['iou']:.3f}", f"{r['bistatic']['iou']:.3f}",
             f"{r['counts_ratio']:.3f}", str(r["confocal"]["rank"]), str(r["bistatic"]["rank"])]
            for r in comparison["rows"]]
    c = comparison["correlation"]
    n = comparison["rows"][0]["confocal"]["n"] if comparison["rows"] else 0
    return (
        "<p>The study's glyphs at the legible geometry rendered under both transports: "
        "confocal (the seed's Eq. 9, what every other section uses) and bistatic (Eq. 8 in "
        f"full: light leaves the face at r1 and returns at r2, the full BRDF; {rings} x "
        f"{angles} face samples, converged in tools/results/study_transport_faces.csv); "
        f"same scenes, noise seeds, reconstruction and identification rule; {n} "
        "reconstructions per material and transport. Margin: mean NCC of the true glyph "
        "minus the best other (> 0: identified). Rank: by identification, ties by margin. "
        "Counts: bistatic / confocal photon counts.</p>"
        + _table(["material", "class", "identification confocal", "identification bistatic",
                  "margin confocal", "margin bistatic", "IoU confocal", "IoU bistatic",
                  "counts ratio", "rank confocal", "rank bistatic"], rows)
        + f"<p>Rank correlation: Spearman {_fmt(c['rank']['spearman'])}, Kendall "
        f"{_fmt(c['rank']['kendall'])}; of the accuracies: Spearman "
        f"{_fmt(c['accuracy']['spearman'])}, Kendall {_fmt(c['accuracy']['kendall'])}; of "
        f"the margins: Spearman {_fmt(c['margin']['spearman'])}, Kendall "
        f"{_fmt(c['margin']['kendall'])}.</p>"
        f"<p><b>{html.escape(comparison['statement'])}</b></p>"
        "<p>Regenerate: <code>python -m clnlos study --transport both</code> (this section; "
        "adds 80 bistatic samples to the quick study, about 8 s each on 2 cores) or <code>python "
        "tools/study_transport.py</code> (the table alone, "
        "tools/results/study_transport.{csv,json}).</p>")

"""The report's section on the legibility judge: its three held-out splits beside the
majority and one-feature baselines, the reliability diagrams, the family split (every real
capture's thinning ladder) and the real captures thinned to fewer photons
(:mod:`clnlos.study.judge.study`, :mod:`clnlos.study.judge.real`,
:mod:`clnlos.study.real.thinning`).
"""

from __future__ import annotations

import html

import numpy as np

from clnlos.study.judge.heldout import SPLITS
from clnlos.study.real.thinning import thinning_figure

TARGETS = {"balanced_accuracy": 0.85, "auc": 0.9, "ece": 0.08}  # the bar, shown


def fig_reliability(results):
    """One reliability diagram per split (observed share of legible reconstructions against
    the mean P(legible) per bin, the bins' counts beneath) and the balanced accuracies of
    the judge and its baselines."""
    from matplotlib.figure import Figure

    splits = results["classifier"]["splits"]
    detail = results["judge"]["splits"]
    fig = Figure(figsize=(4.0 * (len(SPLITS) + 1), 4.2), layout="constrained")
    ax = fig.subplots(1, len(SPLITS) + 1)
    for a, name in zip(ax, SPLITS, strict=False):
        rel = detail[name]["reliability"]
        edges = np.asarray(rel["edges"])
        centres = (edges[1:] + edges[:-1]) / 2
        have = [i for i, c in enumerate(rel["count"]) if c]
        a.plot([0, 1], [0, 1], ":", color="gray", label="calibrated")
        a.plot([rel["confidence"][i] for i in have], [rel["frequency"][i] for i in have],
               "o-", label="judge")
        counts = np.asarray(rel["count"], float)
        a.bar(centres, counts / max(counts.sum(), 1.0), width=edges[1] - edges[0],
              alpha=0.25, color="tab:blue", label="share of samples")
        s = splits[name]
        a.set(xlim=(0, 1), ylim=(0, 1), xlabel="mean P(legible) in the bin",
              ylabel="share legible (observed)",
              title=f"held out by {name}: ECE {s['ece']:.3f}\nAUC {s['auc']:.3f}, n "
                    f"{detail[name]['n']}")
        a.legend(fontsize=8, loc="upper left")
    a = ax[-1]
    x = np.arange(len(SPLITS))
    w = 0.27
    for k, (key, label) in enumerate((("balanced_accuracy", "judge"),
                                      ("baseline", "one feature (training cut)"))):
        a.bar(x + (k - 0.5) * w, [splits[n][key] for n in SPLITS], w, label=label)
    a.bar(x + 1.5 * w, [0.5] * len(SPLITS), w, label="majority class", color="gray")
    a.axhline(TARGETS["balanced_accuracy"], color="k", ls=":", label="target 0.85")
    a.set(xticks=x, xticklabels=SPLITS, ylim=(0, 1), ylabel="balanced accuracy",
          title="balanced accuracy (P >= 0.5 is legible)")
    a.legend(fontsize=8, loc="lower right")
    return fig


def _split_rows(results, model: str = "capture") -> list[list[str]]:
    key = "splits" if model == "capture" else "volume_splits"
    splits = results["classifier"][key]
    detail = results["judge"][key]
    rows = []
    for name in SPLITS:
        s, d = splits[name], detail[name]
        feats = sorted(set(f for f in d["baseline_features"] if f))
        rows.append([model, name, str(d["n"]), str(d["legible"]),
                     f"{s['balanced_accuracy']:.3f}", f"{s['auc']:.3f}", f"{s['ece']:.3f}",
                     f"{s['majority']:.3f}", f"{s['baseline']:.3f}",
                     html.escape(", ".join(feats)),
                     " / ".join(f"{f['balanced_accuracy']:.2f}" for f in d["folds"])])
    return rows


def _thinning_rows(rows) -> list[list[str]]:
    return [[html.escape(r["capture"]), f"{r['fraction']:g}", f"{r['photons']:.4g}",
             f"{r['p_legible']:.3f}"] for r in rows]


def _family_rows(family: dict) -> list[list[str]]:
    return [[html.escape(r["capture"]), html.escape(r.get("family", "")),
             f"{r['fraction']:g}", f"{r['photons']:.4g}", f"{r['p_legible']:.3f}",
             f"{r['p_volume']:.3f}", f"{r['agreement']:.2f}", r["reference"]]
            if "error" not in r else [html.escape(r["capture"]), html.escape(r["family"]),
                                      "-", "-", "-", "-", "-",
                                      html.escape("not read: " + r["error"])]
            for r in family["rows"]]


def family_html(results, family_mips, table, png) -> list[str]:
    """The family split: trained on simulations only, every real capture's ladder."""
    family = results["classifier"].get("family") or {"rows": []}
    if not family["rows"]:
        return ["<p>No real captures: run the study with <code>--real-data DIR</code> (its "
                "<code>cdt/</code> and <code>lct/</code> captures) for the family split.</p>"]
    ref = family["reference"]
    caps = family["captures"]
    out = [
        "<h3>Held out by family: trained on simulations only, tested on every real capture"
        "</h3>",
        ("<p>Each real capture binomially thinned (nested, seeded) and reconstructed with the "
         "judge's recipe together with two binomial halves of its photons; P(legible) of the "
         "capture model (and of the MIP-only volume model). The reference label (testing "
         f"only): legible where the rung's MIP agrees with the full-photon MIP by Pearson r "
         f">= {ref['legible_at_least']:g}, gone below {ref['gone_below']:g}, undecided "
         f"between. Against it over the {family['n_decided']} decided rungs: balanced "
         f"accuracy {_fmt(family['balanced_accuracy'])}, AUC {_fmt(family['auc'])}.</p>"),
        "<p>" + " ".join(html.escape(
            f"{c}: P {v['p_full']:.2f} with all photons, largest rise {v['largest_rise']:+.2f}"
            f", P {_fmt(v['p_first_gone'])} where the image is first gone "
            f"({'meets' if v['passes'] else 'misses'} the bar P >= 0.8 at full photons, "
            "falling within 0.05, < 0.5 where gone).") if "error" not in v else
            html.escape(f"{c}: not read ({v['error']}).") for c, v in caps.items()) + "</p>"]
    if family_mips:
        out.append(f"<img alt='family split' src='data:image/png;base64,"
                   f"{png(thinning_figure(family_mips))}'/>")
    out.append(table(["capture", "family", "fraction", "photons", "P(legible)",
                      "P (volume model)", "r with full", "reference"], _family_rows(family)))
    return out


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def classifier_section(results, thinning, table, png, family_mips=None) -> list[str]:
    """HTML of the section: ``thinning`` the real rows with their MIPs (None without real
    captures), ``family_mips`` the family split's rows with theirs, ``table(header, rows)``
    and ``png(fig)`` the report's own helpers."""
    judge = results["judge"]
    title = "The legibility judge: held-out splits, calibration, real captures thinned"
    cost = judge["cost_s"]
    out = [f"<h3>{html.escape(title)}</h3>", (
        f"<p>What it predicts: P(legible), legible meaning {html.escape(judge['label'])}. "
        f"The model: {html.escape(judge['model'])}; the capture model reads "
        f"{html.escape(', '.join(judge['capture_features']))} (the last two: the agreement "
        "of the reconstructions of two binomial halves of the photons), the volume model "
        "(any reconstruction) the MIP's only; every feature is a ratio measured on the image, "
        "unchanged by the target's place and scale in the scan. Trained on "
        f"{judge['twins']['scenes']} simulated twins of the real CDT and LCT families "
        f"({len(judge['twins']['geometries'])} geometries, "
        f"{len(judge['twins']['materials'])} materials, each a thinning ladder: "
        f"{judge['n']} reconstructions, {judge['legible']} legible; the volume model adds "
        "the study's own glyph reconstructions, "
        f"{judge['n_volume']} in all). Cost: twins {cost['twins_cpu']:.1f} s CPU, training "
        f"and validation {cost['training_cpu']:.1f} s CPU. Each split is a grouped cross-"
        f"validation ({', '.join(f'{k}: {v} folds' for k, v in judge['split_folds'].items())})"
        ": every reconstruction is predicted by a model that saw nothing of its glyph, "
        "geometry or material. The one-feature baseline is the best single feature with its "
        "cut chosen on the training split; the majority baseline's accuracy is given (its "
        "balanced accuracy is 0.5).</p>"),
        table(["model", "held out by", "n", "legible", "balanced accuracy", "AUC", "ECE",
               "majority (accuracy)", "one feature (balanced accuracy)", "its features",
               "per fold"], _split_rows(results) + _split_rows(results, "volume")),
        f"<p>{html.escape(baseline_verdict(results['classifier']['splits']))}</p>",
        f"<img alt='reliability' src='data:image/png;base64,{png(fig_reliability(results))}'/>",
        *family_html(results, family_mips, table, png)]
    if not thinning:
        return out
    out += [(
        "<p>The real CDT captures thinned as before and reconstructed with the study's method "
        "and defaults; under each MIP the volume model's P(legible) (green: legible), and "
        "against photons per capture: "
        f"{', '.join(f'{r:g}' for r in sorted({r['fraction'] for r in thinning}, reverse=True))}"
        " of the photons.</p>"),
        f"<img alt='thinned real captures' src='data:image/png;base64,"
        f"{png(thinning_figure(thinning))}'/>",
        "<p>" + " ".join(html.escape(_trend(thinning, n))
                         for n in dict.fromkeys(r["capture"] for r in thinning))
        + " " + html.escape(real_verdict(thinning)) + "</p>",
        table(["capture", "fraction", "photons", "P(legible)"], _thinning_rows(thinning))]
    return out


def _trend(rows, capture: str) -> str:
    """One sentence: P(legible) of ``capture`` at its most photons and the largest rise of
    P as the photons fall (the thinned series should only fall)."""
    rs = sorted((r for r in rows if r["capture"] == capture), key=lambda r: -r["photons"])
    p = [r["p_legible"] for r in rs]
    rise = max((b - a for a, b in zip(p, p[1:], strict=False)), default=0.0)
    return (f"{capture}: P(legible) {p[0]:.2f} with all {rs[0]['photons']:.3g} photons, "
            f"{p[-1]:.2f} with {rs[-1]['photons']:.3g}; largest rise as photons fall "
            f"{max(rise, 0.0):+.2f}.")


def baseline_verdict(splits: dict) -> str:
    """One sentence: where the judge's balanced accuracy is below its one-feature baseline's
    (there the feature is the better judge)."""
    below = [k for k in SPLITS if splits[k]["balanced_accuracy"] < splits[k]["baseline"]]
    if not below:
        return "The judge beats its one-feature baseline on every split."
    return (f"Held out by {' and by '.join(below)} the judge is below its one-feature baseline: "
            "there the feature, thresholded on the training split, is the better judge.")


def real_verdict(rows: list[dict], tolerance: float = 0.05) -> str:
    """One sentence on whether P(legible) on the real captures can be read as a verdict: it
    has seen only simulations; a classifier inside its domain gives a P that falls as the
    photons fall (within ``tolerance``) and is high where the letters are clear."""
    caps = list(dict.fromkeys(r["capture"] for r in rows))
    full = {c: max((r for r in rows if r["capture"] == c), key=lambda r: r["photons"])
            for c in caps}
    rises = {}
    for c in caps:
        p = [r["p_legible"] for r in sorted((r for r in rows if r["capture"] == c),
                                            key=lambda r: -r["photons"])]
        rises[c] = max((b - a for a, b in zip(p, p[1:], strict=False)), default=0.0)
    not_falling = [c for c in caps if rises[c] > tolerance]
    low = [c for c in caps if full[c]["p_legible"] < 0.5]
    if not not_falling and not low:
        return ("On every real capture P(legible) is at least 0.5 with all its photons and "
                "falls as they are thinned.")
    parts = []
    if low:
        parts.append(f"P(legible) below 0.5 with all photons on {', '.join(low)}")
    if not_falling:
        parts.append(f"rising by more than {tolerance:g} as photons fall on "
                     f"{', '.join(not_falling)}")
    return ("Not a verdict on these captures: the judge has seen only simulations, and "
            "here it gives " + "; ".join(parts) + ". Read the MIPs above by eye.")

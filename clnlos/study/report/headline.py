"""The report's first screen: the one figure that answers the study's question and at most
five one-sentence findings with their numbers.

The figure (:func:`fig_headline`): the exposure needed per material x target x inversion with
its interval and the curves it comes from (:func:`clnlos.study.report.plan.fig_plan`); where
the study has a material table, the identification per material at its legible target beside
them (closest of the K blurred glyph templates, Wilson 95% intervals) for the Lambertian
inversion, the material's own BRDF ("known"), the lobe chosen from the capture ("auto") and
the time-integrated measurement alone.

The findings claim no threshold beyond the sweep and no order where two Wilson intervals
overlap.
"""

from __future__ import annotations

import html

import numpy as np

from clnlos.study.score.legibility import wilson_interval
from clnlos.study.report.figures import INVERSION_LABELS, short_name
from clnlos.study.real.materials import ratio_text
from clnlos.study.report.plan import fig_plan, plan_findings

# the BRDF classes, most diffuse first (the order of the rows)
CLASS_ORDER = ("Lambertian", "strong diffuse", "strong specular + diffuse", "strong specular")
DIFFUSE = ("Lambertian", "strong diffuse")
SPECULAR = ("strong specular",)
SERIES = ("lambertian", "known", "auto", "measurement")
STYLES = {"lambertian": ("o", "tab:blue"), "known": ("s", "tab:orange"),
          "auto": ("^", "tab:green"), "measurement": ("D", "0.35")}
HEADLINE_ID = "headline"  # the <img id> the first-screen test measures


def legible_geometry(results) -> dict:
    return next(g for g in results["geometries"] if g["name"] == results["legible_geometry"])


def series_identification(m: dict, series: str) -> dict | None:
    """A material entry's identification summary for one series (None: not run)."""
    if series == "lambertian":
        return m["identification"]
    if series == "measurement":
        return m.get("measurement_identification")
    inv = m.get("inversions", {}).get(series)
    return None if inv is None else inv["identification"]


def pooled(summaries) -> dict | None:
    """Identification pooled over several summaries: successes and trials added, a Wilson
    95% interval on the total (None without trials)."""
    rows = [s for s in summaries if s is not None and s.get("n")]
    n = sum(s["n"] for s in rows)
    if not n:
        return None
    k = sum(int(round(s["accuracy"] * s["n"])) for s in rows)
    return {"accuracy": k / n, "ci": list(wilson_interval(k, n)), "n": n}


def class_identification(results, classes, series: str) -> dict | None:
    return pooled(series_identification(m, series) for m in legible_geometry(results)["materials"]
                  if m["brdf_class"] in classes)


def order_of(a: dict | None, b: dict | None) -> int | None:
    """+1 when ``a``'s Wilson interval lies wholly above ``b``'s, -1 below, 0 when they
    overlap (no verdict), None when either is missing."""
    if a is None or b is None:
        return None
    if a["ci"][0] > b["ci"][1]:
        return 1
    if a["ci"][1] < b["ci"][0]:
        return -1
    return 0


def pct_ci(s: dict) -> str:
    return (f"{100 * s['accuracy']:.0f}% [{100 * s['ci'][0]:.0f}, {100 * s['ci'][1]:.0f}] "
            f"(n {s['n']})")


def _identification_panel(ax, results) -> None:
    geo = legible_geometry(results)
    mats = sorted(geo["materials"], key=lambda m: (
        CLASS_ORDER.index(m["brdf_class"]) if m["brdf_class"] in CLASS_ORDER else 9,
        -m["identification"]["accuracy"]))
    present = [s for s in SERIES if any(series_identification(m, s) for m in mats)]
    y = np.arange(len(mats))[::-1].astype(float)
    step = 0.8 / max(len(present), 1)
    for k, s in enumerate(present):
        marker, colour = STYLES[s]
        pts = [(yy + 0.4 - (k + 0.5) * step, series_identification(m, s))
               for yy, m in zip(y, mats, strict=True)]
        pts = [(yy, i) for yy, i in pts if i is not None]
        acc = np.array([i["accuracy"] for _, i in pts])
        err = [np.clip(acc - [i["ci"][0] for _, i in pts], 0, None),
               np.clip([i["ci"][1] for _, i in pts] - acc, 0, None)]
        ax.errorbar(acc, [yy for yy, _ in pts], xerr=err, fmt=marker, color=colour, ms=4,
                    capsize=2, lw=1, label=INVERSION_LABELS.get(s, s)
                    + (" inversion" if s == "lambertian" else ""))
    chance = mats[0]["identification"]["chance"]
    ax.axvline(chance, color="gray", ls=":", lw=0.8, label=f"chance 1/K = {chance:.2f}")
    level = results["options"]["legible_fraction"]
    ax.axvline(level, color="gray", ls="--", lw=0.8, label=f"legible ({level:g})")
    ax.set_yticks(y)
    ax.set_yticklabels([f"{short_name(m['name'], 24)}\n{m['brdf_class']}" for m in mats],
                       fontsize=6.5)
    ax.set(xlim=(-0.02, 1.02), ylim=(-0.6, len(mats) - 0.4),
           xlabel="identification accuracy (Wilson 95% interval)",
           title=f"which glyph? per material, {geo['letter_height_m']:g} m letters at "
                 f"{geo['depth_m']:g} m, {results['options']['grid']['exposure_s']:g} s per point")
    ax.title.set_fontsize(9)
    ax.legend(fontsize=6.5, ncol=3, loc="upper center", bbox_to_anchor=(0.45, -0.13),
              frameon=False)


def fig_headline(results):
    """The headline figure: the exposure needed per material and inversion with the curves
    it comes from (:func:`clnlos.study.report.plan.fig_plan`), after the identification per
    material and series where the study has a material table; without an exposure sweep, the
    identification panel alone."""
    import matplotlib.pyplot as plt  # optional dependency: only when a report draws

    table = bool(results.get("geometries"))
    if results.get("plan"):
        return fig_plan(results, (lambda ax: _identification_panel(ax, results))
                        if table else None)
    fig, ax = plt.subplots(1, 1, figsize=(8.0, 4.3), constrained_layout=True)
    _identification_panel(ax, results)
    return fig


def headline_findings(results) -> list[str]:
    """At most five one-sentence findings, each with its numbers (HTML-escaped text): the
    plan's (:func:`clnlos.study.report.plan.plan_findings`) first, then the table's."""
    plan = plan_findings(results)
    if not results.get("geometries"):
        return plan[:5]
    return (plan[:2] + table_findings(results))[:5]


def table_findings(results) -> list[str]:
    """The material table's findings (HTML-escaped)."""
    out = []
    d_l = class_identification(results, DIFFUSE, "lambertian")
    s_l = class_identification(results, SPECULAR, "lambertian")
    chance = legible_geometry(results)["materials"][0]["identification"]["chance"]
    if d_l and s_l:
        verdict = {1: "the material decides what this inversion reads",
                   -1: "strong-specular targets read better here",
                   0: "the intervals overlap: no order at this sample size"}[order_of(d_l, s_l)]
        out.append(f"With the Lambertian inversion, diffuse targets are identified in "
                   f"{pct_ci(d_l)} of reconstructions and strong-specular ones in "
                   f"{pct_ci(s_l)} (chance {100 * chance:.0f}%): {verdict}.")
    for series, what in (("known", "with the material's own BRDF"),
                         ("auto", "with the lobe chosen from the capture (brdf auto)")):
        s_x = class_identification(results, SPECULAR, series)
        if s_x and s_l:
            o = order_of(s_x, s_l)
            verdict = {1: "higher than the Lambertian inversion's",
                       -1: "lower than the Lambertian inversion's",
                       0: "not distinguishable from the Lambertian inversion's "
                          "(the intervals overlap)"}[o]
            out.append(f"Strong-specular targets {what}: {pct_ci(s_x)}, {verdict}.")
    s_m = class_identification(results, SPECULAR, "measurement")
    if s_m and s_l:
        o = order_of(s_m, s_l)
        verdict = {1: "the data hold more of the glyph than the Lambertian inversion reads",
                   -1: "below the Lambertian inversion",
                   0: "not distinguishable from the Lambertian inversion (the intervals "
                      "overlap)"}[o]
        out.append(f"The time-integrated measurement alone identifies strong-specular "
                   f"glyphs in {pct_ci(s_m)}: {verdict}.")
    real = real_materials_finding(results)
    if real:
        out = [real, *out[:4]]
    return [html.escape(s) for s in out[:5]]


def real_materials_finding(results) -> str | None:
    """The real captures' answer (``results["real_materials"]``: the diffuse S against the
    retroreflective S of the same rig, and what their simulated twins predict), one sentence."""
    section = results.get("real_materials") or {}
    rows = [h for h in section.get("headline", ()) if h.get("ratio") is not None]
    if not rows:
        return None
    h = rows[0]
    text = (f"On real captures of one rig (O'Toole et al. 2018), the diffuse S needs "
            f"{ratio_text(h, '.2g')} the photons of the retroreflective S to "
            f"keep its image ({h['diffuse']['photons']:.2g} against "
            f"{h['retroreflective']['photons']:.2g}, {h['inversion'].upper()}; "
            f"{h.get('signal_ratio', float('nan')):.0f}x counting only the photons above "
            "the floor of dark counts and ambient light)")
    twins = [t for t in section.get("twin_headline", ()) if t.get("ratio") is not None]
    if twins:
        t = twins[0]
        text += f"; their simulated twins predict {ratio_text(t, '.2g')}"
    return text + "."


def headline_html(results, png) -> str:
    """The first screen: the headline figure (``<img id="headline">``) and the findings;
    ``png(fig)``: a figure's base64 PNG."""
    items = "".join(f"<li>{s}</li>" for s in headline_findings(results))
    alt = "exposure needed per material and inversion, and the curves it comes from"
    return (f"<img id='{HEADLINE_ID}' alt='{alt}' src='data:image/png;base64,"
            f"{png(fig_headline(results))}'/>"
            f"<ol class='findings'>{items}</ol>")


def probe_script() -> str:
    """A script that writes the headline figure's box (px from the page top, after load)
    into ``<body data-headline-top data-headline-bottom>``, read by tools/check_report.py."""
    return ("<script>addEventListener('load', function () {var e = document.getElementById("
            f"'{HEADLINE_ID}'); if (e) {{var r = e.getBoundingClientRect(); "
            "document.body.dataset.headlineTop = String(Math.round(r.top + scrollY)); "
            "document.body.dataset.headlineBottom = String(Math.round(r.bottom + scrollY));"
            "}});</script>")

"""The report's first screen: the one figure that answers "how does the material change
what I can read?" and at most five one-sentence findings with their numbers.

The figure (:func:`fig_headline`) has two panels at the legible geometry:

* identification per material (closest of the K blurred glyph templates, Wilson 95%
  intervals) for the Lambertian inversion, the inversion with the material's own BRDF
  ("known"), the lobe chosen from the capture ("auto") and the time-integrated measurement
  alone;
* the photons each swept material needs for identification >= LEGIBLE_ACCURACY, per
  inversion and for the measurement alone: the exposure sweep's bracket, from the last
  exposure that fell short to the first that reached it (an open end where the smallest
  exposure tried already reached it or the largest did not), beside the rows of real
  captures when given (``real_rows``).

A real-capture row is ``(label, photons, (lo, hi))``: ``label`` a str, ``photons`` the
photons detected (per capture, as the simulated rows count them) at which it first reads,
None where it never does, and ``(lo, hi)`` the bracket of the photons needed (either may be
None: open below / above). JSON lists ``[label, photons, [lo, hi]]`` are read the same.

The findings claim no threshold beyond the sweep ("<= 0.001 s (the smallest tried)") and no
order where two Wilson intervals overlap.
"""

from __future__ import annotations

import html

import numpy as np

from clnlos.study.score.legibility import LEGIBLE_ACCURACY, wilson_interval
from clnlos.study.report.figures import INVERSION_LABELS, short_name

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


def sweep_bracket(points, target: float = LEGIBLE_ACCURACY):
    """(lo, hi) of a sweep ``points`` [(x, accuracy), ...] in x order: hi the first x whose
    accuracy reaches ``target``, lo the x before it; lo None where the first x already
    reaches it, hi None where none does (lo then the largest x)."""
    prev = None
    for x, acc in points:
        if acc >= target:
            return prev, x
        prev = x
    return prev, None


def bracket_text(lo, hi, unit: str) -> str:
    """A sweep threshold in words, never beyond what was swept."""
    if hi is None:
        return f"> {lo:g} {unit} (the largest tried)" if lo is not None else "not swept"
    if lo is None:
        return f"<= {hi:g} {unit} (the smallest tried)"
    return f"{lo:g} to {hi:g} {unit}"


def exposure_points(results, material: str, series: str, value_key: str = "value"):
    """[(exposure or photons, accuracy), ...] of the exposure sweep of one material and
    series, in exposure order (the measurement alone: from the Lambertian rows)."""
    inv = "lambertian" if series == "measurement" else series
    key = "measurement_identification" if series == "measurement" else "identification"
    rows = sorted((r for r in results.get("legibility_sweeps", ())
                   if r["variable"] == "exposure_s" and r["material"] == material
                   and r.get("inversion", "lambertian") == inv and key in r),
                  key=lambda r: r["value"])
    x = "photon_counts" if value_key == "photons" else "value"
    return [(r[x], r[key]["accuracy"]) for r in rows]


def photons_needed_rows(results) -> list[tuple[str, str, float | None, float | None]]:
    """(material, series, lo, hi) of the photons needed per swept material and series (the
    sweep's bracket, :func:`sweep_bracket`)."""
    mats = list(dict.fromkeys(r["material"] for r in results.get("legibility_sweeps", ())
                              if r["variable"] == "exposure_s"))
    out = []
    for m in mats:
        for s in SERIES:
            pts = exposure_points(results, m, s, "photons")
            if pts:
                out.append((m, s, *sweep_bracket(pts)))
    return out


def real_row(row) -> tuple[str, float | None, float | None, float | None]:
    """(label, photons, lo, hi) of one real-capture row (tuple or JSON list)."""
    label, photons, interval = row
    lo, hi = (interval or (None, None))
    return str(label), photons, lo, hi


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
    ax.axvline(LEGIBLE_ACCURACY, color="gray", ls="--", lw=0.8,
               label=f"legible ({LEGIBLE_ACCURACY:g})")
    ax.set_yticks(y)
    ax.set_yticklabels([f"{short_name(m['name'], 24)}\n{m['brdf_class']}" for m in mats],
                       fontsize=6.5)
    ax.set(xlim=(-0.02, 1.02), ylim=(-0.6, len(mats) - 0.4),
           xlabel="identification accuracy (Wilson 95% interval)",
           title=f"which glyph? per material, {geo['letter_height_m']:g} m letters at "
                 f"{geo['depth_m']:g} m, 0.1 s per point")
    ax.title.set_fontsize(9)
    ax.legend(fontsize=6.5, ncol=3, loc="upper center", bbox_to_anchor=(0.45, -0.13),
              frameon=False)


def _photons_panel(ax, results, real_rows) -> None:
    rows = [(f"{short_name(m, 18)}, {INVERSION_LABELS.get(s, s)}", s, lo, hi)
            for m, s, lo, hi in photons_needed_rows(results)]
    rows += [(f"real: {label}", "real", lo, hi) for label, _, lo, hi in
             (real_row(r) for r in (real_rows or ()))]
    if not rows:
        ax.text(0.5, 0.5, "no exposure sweep in this run", ha="center", va="center",
                transform=ax.transAxes)
        ax.set_axis_off()
        return
    finite = [v for _, _, lo, hi in rows for v in (lo, hi) if v]
    x_min, x_max = min(finite) / 4, max(finite) * 4
    for k, (label, s, lo, hi) in enumerate(rows):
        yy = len(rows) - 1 - k
        marker, colour = STYLES.get(s, ("*", "k"))
        a, b = lo if lo else x_min, hi if hi else x_max
        ax.plot([a, b], [yy, yy], color=colour, lw=2.5, alpha=0.6, solid_capstyle="butt")
        if hi:
            ax.plot(hi, yy, marker, color=colour, ms=5)
        if lo is None and hi:
            ax.annotate("", (x_min, yy), (hi, yy), arrowprops={"arrowstyle": "->",
                                                               "color": colour})
        if hi is None and lo:
            ax.annotate("", (x_max, yy), (lo, yy), arrowprops={"arrowstyle": "->",
                                                               "color": colour})
    ax.set_xscale("log")
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels([r[0] for r in rows][::-1], fontsize=6.5)
    ax.set(xlim=(x_min, x_max), ylim=(-0.6, len(rows) - 0.4),
           xlabel="photons detected per capture",
           title=f"photons needed for identification >= {LEGIBLE_ACCURACY:g} (simulated);\n"
                 "real (*): to keep the full-photon image (bar: last short - first "
                 "legible; arrow: beyond)")
    ax.title.set_fontsize(9)


def fig_headline(results, real_rows=None):
    """The headline figure: identification per material and series (left), the photons
    needed per swept material and series, with ``real_rows`` (real captures, the module's
    row format) beside them (right)."""
    import matplotlib.pyplot as plt  # optional dependency: only when a report draws

    fig, ax = plt.subplots(1, 2, figsize=(11.5, 4.3), width_ratios=(1.35, 1),
                           constrained_layout=True)
    _identification_panel(ax[0], results)
    _photons_panel(ax[1], results, real_rows)
    return fig


def headline_findings(results) -> list[str]:
    """At most five one-sentence findings, each with its numbers (HTML-escaped text)."""
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
    parts = []
    for m in dict.fromkeys(r["material"] for r in results.get("legibility_sweeps", ())
                           if r["variable"] == "exposure_s"):
        brackets = [(s, *sweep_bracket(pts)) for s in ("lambertian", "known", "auto")
                    if (pts := exposure_points(results, m, s))]
        reached = [(hi, k, s, lo) for k, (s, lo, hi) in enumerate(brackets) if hi is not None]
        if reached:  # the best inversion; a tie goes to the earlier one
            hi, _, s, lo = min(reached)
            parts.append(f"{short_name(m, 22)} {bracket_text(lo, hi, 's')} "
                         f"({INVERSION_LABELS.get(s, s)})")
        elif brackets:
            parts.append(f"{short_name(m, 22)} {bracket_text(brackets[0][1], None, 's')}")
    if parts:
        out.append(f"Exposure per scan point needed for identification >= "
                   f"{LEGIBLE_ACCURACY:g} (best inversion): " + "; ".join(parts) + ".")
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
    lo, hi = h["ratio_range"]
    text = (f"On real captures of one rig (O'Toole et al. 2018), the diffuse S needs "
            f"{h['ratio']:.0f}x [{lo:.0f}, {hi:.0f}] the photons of the retroreflective S to "
            f"keep its image ({h['diffuse']['photons']:.2g} against "
            f"{h['retroreflective']['photons']:.2g}, {h['inversion'].upper()}; "
            f"{h.get('signal_ratio', float('nan')):.0f}x counting only the photons above "
            "the floor of dark counts and ambient light)")
    twins = [t for t in section.get("twin_headline", ()) if t.get("ratio") is not None]
    if twins:
        t = twins[0]
        text += (f"; their simulated twins predict {t['ratio']:.0f}x "
                 f"[{t['ratio_range'][0]:.0f}, {t['ratio_range'][1]:.0f}]")
    return text + "."


def headline_html(results, png, real_rows=None) -> str:
    """The first screen: the headline figure (``<img id="headline">``) and the findings;
    ``png(fig)``: a figure's base64 PNG."""
    items = "".join(f"<li>{s}</li>" for s in headline_findings(results))
    alt = "identification and photons needed per material and inversion"
    return (f"<img id='{HEADLINE_ID}' alt='{alt}' src='data:image/png;base64,"
            f"{png(fig_headline(results, real_rows))}'/>"
            f"<ol class='findings'>{items}</ol>")


def probe_script() -> str:
    """A script that writes the headline figure's box (px from the page top, after load)
    into ``<body data-headline-top data-headline-bottom>``, read by tools/check_report.py."""
    return ("<script>addEventListener('load', function () {var e = document.getElementById("
            f"'{HEADLINE_ID}'); if (e) {{var r = e.getBoundingClientRect(); "
            "document.body.dataset.headlineTop = String(Math.round(r.top + scrollY)); "
            "document.body.dataset.headlineBottom = String(Math.round(r.bottom + scrollY));"
            "}});</script>")

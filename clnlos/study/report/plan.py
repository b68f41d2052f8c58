"""The report's answer to "how long must I expose?": the exposure needed per material x target
x inversion with its interval (:func:`exposure_panel`), the curves it comes from
(:func:`curves_panel`), the table, the reconstructions around the threshold
(:func:`fig_threshold_gallery`) and the real captures beside their twins
(:func:`real_check_html`). matplotlib is imported where a figure is drawn."""

from __future__ import annotations

import html
import math

import numpy as np

from clnlos.study.findings.exposure import BELOW, BEYOND
from clnlos.study.findings.summary import need_text
from clnlos.study.report.figures import INVERSION_LABELS, short_name

METHOD_COLOURS = {"lct": "tab:blue", "fk": "tab:purple", "iterative": "tab:green"}
REFLECTANCE_MARKERS = {"lambertian": "o", "known": "s", "auto": "^"}
REFLECTANCE_STYLES = {"lambertian": "-", "known": "--", "auto": ":"}


def inversion_label(row: dict) -> str:
    return f"{row['method'].upper() if row['method'] != 'iterative' else 'iterative'}, " \
           f"{INVERSION_LABELS.get(row['reflectance'], row['reflectance'])}"


def row_label(row: dict) -> str:
    at = "".join(f", {k.split('_')[0]} {v:g}" for k, v in row["at"].items())
    return f"{short_name(row['material'], 20)} | {short_name(row['target'], 10)}{at}"


def exposure_panel(ax, rows: list[dict], level: float) -> None:
    """One line per material x target (x the other swept values); per inversion the
    exposure needed (marker) and its interval (bar); arrows where it lies beyond the sweep
    or below its smallest exposure."""
    groups = list(dict.fromkeys(row_label(r) for r in rows))
    invs = list(dict.fromkeys((r["method"], r["reflectance"]) for r in rows))
    swept = [p["exposure_s"] for r in rows for p in r["curve"]]
    x_min, x_max = min(swept) / 3, max(swept) * 3
    step = 0.8 / max(len(invs), 1)
    for r in rows:
        k = invs.index((r["method"], r["reflectance"]))
        y = len(groups) - 1 - groups.index(row_label(r)) + 0.4 - (k + 0.5) * step
        colour = METHOD_COLOURS.get(r["method"], "k")
        marker = REFLECTANCE_MARKERS.get(r["reflectance"], "o")
        lo, hi = r["exposure_needed_interval_s"]
        if r["status"] == BEYOND:  # more than the largest exposure tried
            last = r["bracket_s"][0]
            ax.annotate("", (x_max, y), (last, y), arrowprops={"arrowstyle": "->",
                                                               "color": colour, "lw": 1.5})
            ax.plot(last, y, "|", color=colour, ms=8)
            continue
        if r["status"] == BELOW:
            ax.annotate("", (x_min, y), (hi, y), arrowprops={"arrowstyle": "->",
                                                             "color": colour, "lw": 1.5})
            ax.plot(hi, y, marker, color=colour, ms=6, mfc="none")
            continue
        ax.plot([lo, hi], [y, y], color=colour, lw=3, alpha=0.45, solid_capstyle="butt")
        ax.plot(r["exposure_needed_s"], y, marker, color=colour, ms=6,
                mec="k" if r.get("best") else colour)
    for m, refl in invs:
        ax.plot([], [], REFLECTANCE_MARKERS.get(refl, "o"), color=METHOD_COLOURS.get(m, "k"),
                label=inversion_label({"method": m, "reflectance": refl}))
    ax.set_xscale("log")
    ax.set_yticks(range(len(groups)))
    ax.set_yticklabels(groups[::-1], fontsize=7)
    ax.set(xlim=(x_min, x_max), ylim=(-0.6, len(groups) - 0.4),
           xlabel="exposure per scan point (s)",
           title=f"exposure needed to read the target in {100 * level:.0f}% of realisations"
                 "\n(bar: interval; arrow: beyond the sweep; black edge: the best)")
    ax.title.set_fontsize(9)
    ax.grid(True, which="major", axis="x", lw=0.3, alpha=0.5)
    ax.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3,
              frameon=False)


METHOD_MARKERS = {"lct": "o", "fk": "D", "iterative": "s"}


def curves_panel(ax, rows: list[dict], level: float) -> None:
    """The share of legible realisations against exposure (Wilson 95% intervals; lines: the
    non-decreasing fit), one curve per row: colour the material and target (the method, as
    the exposure panel's, where there is one material and target), line the reflectance
    assumed, marker the method."""
    groups = list(dict.fromkeys(row_label(r) for r in rows))
    by_method = len(groups) == 1
    colours = {g: f"C{k % 10}" for k, g in enumerate(groups)}
    for r in rows:
        e = np.array([p["exposure_s"] for p in r["curve"]])
        f = np.array([p["fraction"] for p in r["curve"]])
        lo = np.array([p["ci"][0] for p in r["curve"]])
        hi = np.array([p["ci"][1] for p in r["curve"]])
        colour = (METHOD_COLOURS.get(r["method"], "k") if by_method
                  else colours[row_label(r)])
        k = list(dict.fromkeys((x["method"], x["reflectance"]) for x in rows)).index(
            (r["method"], r["reflectance"]))
        off = 1 + 0.03 * (k - 1)  # a little apart: the intervals of one rung do not overlap
        ax.errorbar(e * off, f, yerr=[np.clip(f - lo, 0, None), np.clip(hi - f, 0, None)],
                    fmt=METHOD_MARKERS.get(r["method"], "o"), color=colour, ms=3.5,
                    capsize=1.5, lw=0.6, alpha=0.8)
        ax.plot(e, [p["fit"] for p in r["curve"]],
                REFLECTANCE_STYLES.get(r["reflectance"], "-"), color=colour, lw=1.2)
    for g in ([] if by_method else groups):
        ax.plot([], [], "-", color=colours[g], label=g)
    for m, refl in dict.fromkeys((r["method"], r["reflectance"]) for r in rows):
        ax.plot([], [], REFLECTANCE_STYLES.get(refl, "-"), marker=METHOD_MARKERS.get(m, "o"),
                color=METHOD_COLOURS.get(m, "k") if by_method else "0.3",
                label=inversion_label({"method": m, "reflectance": refl}))
    ax.axhline(level, color="gray", ls=":", lw=0.8)
    ax.set_xscale("log")
    ax.set(ylim=(-0.03, 1.03), xlabel="exposure per scan point (s)",
           ylabel="share of realisations legible",
           title="the curves: legible share (Wilson 95%), its monotone fit\n"
                 "(a rung's realisations stop once they rule the level out)")
    ax.title.set_fontsize(9)
    ax.grid(True, which="major", lw=0.3, alpha=0.5)
    ax.legend(fontsize=6, loc="lower right", frameon=False)


def fig_plan(results, identification_panel=None):
    """The first screen's figure: the exposure needed beside the curves it comes from; with
    a material table, ``identification_panel(ax)`` draws the left panel and the exposure
    needed the right one (the curves: :func:`fig_curves`, below the first screen)."""
    import matplotlib.pyplot as plt  # optional dependency: only when a report draws

    rows, level = results["plan"], results["options"]["legible_fraction"]
    n = len(list(dict.fromkeys(row_label(r) for r in rows)))
    h = max(3.6, min(7.0, 1.6 + 0.45 * n))
    if identification_panel is not None:
        fig, ax = plt.subplots(1, 2, figsize=(11.5, max(h, 4.3)), width_ratios=(1.3, 1),
                               constrained_layout=True)
        identification_panel(ax[0])
        exposure_panel(ax[1], rows, level)
        return fig
    fig, ax = plt.subplots(1, 2, figsize=(11.5, h), width_ratios=(1.2, 1),
                           constrained_layout=True)
    exposure_panel(ax[0], rows, level)
    curves_panel(ax[1], rows, level)
    return fig


def fig_curves(results):
    """The curves alone (the share of legible realisations against exposure)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 1, figsize=(8.0, 4.2), constrained_layout=True)
    curves_panel(ax, results["plan"], results["options"]["legible_fraction"])
    return fig


def plan_table(rows: list[dict], table) -> str:
    """The plan's rows as an HTML table (``table(header, rows)``)."""
    head = ["material", "target", "swept with", "inversion", "exposure needed per point",
            "interval", "photons per capture", "interval", "legible at that rung", "best"]
    body = []
    for r in rows:
        lo, hi = r["exposure_needed_interval_s"]
        plo, phi = r["photons_needed_interval"]
        share = ("" if r["legible_fraction"] is None else
                 f"{r['k']}/{r['n']} [{r['legible_interval'][0]:.2f}, "
                 f"{r['legible_interval'][1]:.2f}]")
        body.append([html.escape(r["material"]), html.escape(r["target"]),
                     html.escape(", ".join(f"{k} = {v:g}" for k, v in r["at"].items())),
                     html.escape(inversion_label(r)),
                     html.escape(r["status"] if r["exposure_needed_s"] is None
                                 else f"{r['exposure_needed_s']:.3g} s"),
                     _interval(lo, hi, "s"),
                     "" if r["photons_needed"] is None else f"{r['photons_needed']:.3g}",
                     _interval(plo, phi, ""), share, "yes" if r.get("best") else ""])
    return table(head, body)


def _interval(lo, hi, unit: str) -> str:
    a = "-" if lo is None else f"{lo:.3g}"
    b = "beyond" if hi is None else f"{hi:.3g}"
    return f"{a} to {b}{(' ' + unit) if unit else ''}"


def fig_threshold_gallery(results, plan, res):
    """Per row of the plan: one realisation's front view at each exposure tried (the
    reconstruction a user would see), the first legible rung framed."""
    import matplotlib.pyplot as plt

    rows = results["plan"][:12]
    if not rows:
        return None
    n_e = max(len(r["curve"]) for r in rows)
    fig, axes = plt.subplots(len(rows), n_e, figsize=(1.25 * n_e + 1.6, 1.35 * len(rows) + 0.5),
                             squeeze=False, gridspec_kw={"left": 0.2, "right": 0.98,
                                                         "top": 0.95, "bottom": 0.03,
                                                         "wspace": 0.06, "hspace": 0.35})
    for i, r in enumerate(rows):
        by_e = {}
        for (meta, _), x in zip(plan, res, strict=True):
            if (meta.get("variable") == "exposure_s" and meta.get("sweep") == r["sweep"]
                    and meta["target"] == r["target"] and meta["material"] == r["material"]
                    and meta["method"] == r["method"] and meta["inversion"] == r["reflectance"]
                    and dict(meta.get("at", {})) == r["at"] and meta["k"] == 0):
                by_e.setdefault(meta["value"], x)
        for j in range(n_e):
            ax = axes[i, j]
            ax.set_xticks([])
            ax.set_yticks([])
            if j >= len(r["curve"]):
                ax.set_axis_off()
                continue
            p = r["curve"][j]
            x = by_e.get(p["exposure_s"])
            if x is not None:
                ax.imshow(x["mip"], cmap="gray", origin="lower", vmin=0, vmax=1)
            ok = p["fit"] >= results["options"]["legible_fraction"]
            for s in ax.spines.values():
                s.set_color("tab:green" if ok else "0.7")
                s.set_linewidth(2 if ok else 0.8)
            ax.set_title(f"{p['exposure_s']:.2g} s, {p['k']}/{p['n']}", fontsize=6)
        axes[i, 0].set_ylabel(f"{short_name(r['material'], 16)}\n{inversion_label(r)}",
                              fontsize=6)
    return fig


def real_check_html(results, checks, table, png) -> list[str]:
    """The ``[[real]]`` captures: the table of photons needed measured against predicted,
    the median ratio, the reference front views of each capture and its twin."""
    rows = results.get("real_check") or []
    if not rows:
        return []
    s = results["real_check_summary"]
    out = ["<p>Each real capture of the rig beside its simulated twin (the target "
           "described, or the mask of the capture's own full-photon reconstruction at its "
           "depths), matched to the capture's signal photons and background floor; photons "
           "needed = where the front view's detail NCC with the full-photon image falls below "
           "0.8 along nested binomial thinnings, the bracket refined to 1.5x, median over "
           "the series. Median predicted / measured: "
           + ("-" if s["median_ratio"] is None else f"<b>{s['median_ratio']:.2f}</b>")
           + f"; {s['within_2x']} of {s['n'] - s['n_bounds']} within 2x"
           + (f"; {s['n_bounds']} bound(s)" if s["n_bounds"] else "") + ".</p>"]
    body = []
    for r in rows:
        def ival(v):
            return "-" if v is None else f"{v:.3g}"
        body.append([html.escape(r["name"]), html.escape(r["material"]),
                     html.escape(f"{r['method']} {r['reflectance']}"), f"{r['photons']:.3g}",
                     f"{r['photons_needed_measured']:.3g}",
                     f"{ival(r['photons_needed_measured_interval'][0])}-"
                     f"{ival(r['photons_needed_measured_interval'][1])}",
                     f"{r['photons_needed_predicted']:.3g}",
                     f"{ival(r['photons_needed_predicted_interval'][0])}-"
                     f"{ival(r['photons_needed_predicted_interval'][1])}",
                     f"{(r['ratio_bound'] or '')} {r['ratio']:.2f}",
                     html.escape(r["twin"]["kind"])])
    out.append(table(["capture", "material", "variant", "photons", "needed (measured)",
                      "interval", "needed (twin)", "interval", "twin / real", "twin"], body))
    if checks:
        out.append("<img alt='real captures and their twins' src='data:image/png;base64,"
                   f"{png(fig_real_check(checks))}'/>")
    return out


def fig_real_check(checks):
    """Per capture: its full-photon front view, its twin's, and the score against photons
    along each series (measured: solid, twin: dashed)."""
    import matplotlib.pyplot as plt

    n = len(checks)
    fig, ax = plt.subplots(3, n, figsize=(max(3.0, 2.3 * n), 7.0), squeeze=False,
                           constrained_layout=True)
    for k, c in enumerate(checks):
        for row, key, title in ((0, "reference", "real"), (1, "twin_reference", "twin")):
            im = ax[row, k].imshow(c["arrays"][key], cmap="gray", origin="lower", vmin=0,
                                   vmax=1)
            ax[row, k].set_title(f"{short_name(c['name'], 18)}: {title}", fontsize=7)
            ax[row, k].set_xticks([])
            ax[row, k].set_yticks([])
        for which, ls, photons in (("measured", "-", c["photons"]),
                                   ("predicted", "--", c["photons"])):
            for s in c["series"][which]:
                f, v = zip(*s["tried"], strict=True)
                order = np.argsort(f)
                ax[2, k].plot(np.asarray(f)[order] * photons, np.asarray(v)[order], ls,
                              marker=".", ms=3, lw=0.8,
                              color="tab:blue" if which == "measured" else "tab:orange")
        ax[2, k].axhline(0.8, color="gray", ls=":", lw=0.8)
        ax[2, k].set_xscale("log")
        ax[2, k].set(ylim=(-0.2, 1.05), xlabel="photons")
        ax[2, k].xaxis.label.set_fontsize(7)
        ax[2, k].tick_params(labelsize=6)
    ax[2, 0].set_ylabel("detail NCC with full photons\n(solid real, dashed twin)", fontsize=7)
    fig.colorbar(im, ax=ax[:2, -1], shrink=0.6, label="front view / max")
    return fig


def plan_findings(results) -> list[str]:
    """At most five one-sentence findings of the plan, with their numbers (HTML-escaped)."""
    rows = results.get("plan") or []
    out = []
    level = results["options"]["legible_fraction"]
    for target in dict.fromkeys(r["target"] for r in rows):
        for m in dict.fromkeys(r["material"] for r in rows if r["target"] == target):
            mine = [r for r in rows if r["target"] == target and r["material"] == m
                    and not r["at"]]
            if not mine:
                continue
            best = next((r for r in mine if r.get("best")), None)
            others = "; ".join(f"{inversion_label(r)} {need_text(r)}" for r in mine
                               if r is not best)
            if best is not None:
                out.append(f"{m}, {target}: legible in {100 * level:.0f}% of realisations "
                           f"from {need_text(best)} with {inversion_label(best)}"
                           + (f" ({others})" if others else "") + ".")
            else:
                out.append(f"{m}, {target}: not legible within the sweep with any inversion "
                           f"({others}).")
    albedo = albedo_finding(results)
    if albedo:
        out.insert(1, albedo)
    s = results.get("real_check_summary")
    if s and s["median_ratio"] is not None:
        out.append(f"On {s['n']} real capture(s) of the rig the twins predict the photons "
                   f"needed to within a median ratio of {s['median_ratio']:.2f} "
                   f"({s['within_2x']} within 2x).")
    return [html.escape(x) for x in out[:5]]


def need_range(row: dict) -> tuple[float, float]:
    """The exposure needed of a row as a range: (value, value) where bracketed, (0, the
    smallest tried) where at most that, (the largest tried, inf) beyond the sweep."""
    if row["status"] == BELOW:
        return 0.0, row["exposure_needed_interval_s"][1]
    if row["status"] == BEYOND:
        return row["bracket_s"][0], math.inf
    return row["exposure_needed_s"], row["exposure_needed_s"]


def albedo_finding(results) -> str | None:
    """Where two materials share a BRDF at two albedos: how much longer the darker one must
    be exposed (each one's best inversion; a bound where either need is one)."""
    by_brdf: dict = {}
    for m in results.get("materials_prepared", ()):
        by_brdf.setdefault(m["brdf"], []).append(m)
    rows = results.get("plan") or []
    for mats in by_brdf.values():
        need = {}
        for m in mats:
            best = [r for r in rows if r["material"] == m["name"] and r.get("best")
                    and not r["at"]]
            if best:
                need[m["name"]] = (m["albedo"], need_range(best[0]), best[0])
        if len(need) < 2:
            continue
        (dark, (a1, (lo1, hi1), r1)), (bright, (a2, (lo2, hi2), r2)) = sorted(
            need.items(), key=lambda kv: kv[1][0])[:2]
        if a1 == a2:
            continue
        lo = lo1 / hi2 if hi2 > 0 else math.inf
        hi = hi1 / lo2 if lo2 > 0 else math.inf
        if math.isfinite(lo) and lo == hi:
            ratio = f"{lo:.2g}x"
        elif lo > 0 and math.isfinite(lo):
            ratio = f"at least {lo:.2g}x"
        elif math.isfinite(hi):
            ratio = f"at most {hi:.2g}x"
        else:
            continue
        return (f"{dark} (albedo {a1:g}) needs {ratio} the exposure of {bright} (albedo "
                f"{a2:g}): {need_text(r1)} against {need_text(r2)}.")
    return None

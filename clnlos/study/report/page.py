"""The study report: one self-contained HTML page (PNG figures embedded) beside results.json.

It opens with its answer: the first screen (1400 x 900 px) holds the headline figure and at
most five one-sentence findings (:mod:`clnlos.study.report.headline`), then the seed's Figure 8
side by side (each material's measurement and reconstruction, Lambertian beside its own
BRDF), then the details -- tables, sweeps, the real captures, the classifier, methods, cost --
each in a section the reader unfolds (``<details>``). Laid out for a 1280-1400 px window: a
fixed-width column, tables that scroll inside their own box, figures scaled to the column;
every figure has axes with units and, for images, a colour bar. Scripts mark the page's
body with ``data-overflow`` (whether anything is wider than the window) and the headline
figure's box (``data-headline-top``/``-bottom``, px), which tools/check_report.py reads in
headless Chromium.
"""

from __future__ import annotations

import base64
import html
import io

import numpy as np

from clnlos.config import snr_rule_applies
from clnlos.inverse.methods import auto_snr_rule
from clnlos.io.files import atomic_path
from clnlos.io.outputs import HTML_GENERATOR
from clnlos.study.real import materials as real_materials
from clnlos.study.report.classifier import classifier_section
from clnlos.study.report.headline import headline_html, probe_script
from clnlos.study.score.quality import METRICS
from clnlos.study.report.figures import (
    INVERSION_LABELS,
    SWEEP_AXES,
    fig_brdf,
    fig_cnn,
    fig_figure8,
    fig_identification,
    fig_legibility_sweeps,
    fig_materials,
    fig_metrics,
    fig_sweeps,
    fig_tilt,
    fig_transport,
    short_name,
)
from clnlos.study.findings.transport import fmt_r
from clnlos.study.report.plan import (
    fig_curves,
    fig_threshold_gallery,
    plan_table,
    real_check_html,
)

PAGE_WIDTH_PX = 1180
DPI = 100


def png_base64(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def sweep_condition(variable: str, value: float) -> str:
    """'without the slab', 'at a target depth of 0.9 m', ... for a sweep point."""
    if variable == "slab_thickness_m":
        return "without the slab" if value == 0 else f"behind a {value * 100:g} cm slab"
    name = SWEEP_AXES.get(variable, variable).split(" (")[0]
    return f"at a {name} of {value:g} m"


def _table(header, rows) -> str:
    h = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<div class='tab'><table><tr>{h}</tr>{body}</table></div>"


STYLE = f"""
body {{ font-family: sans-serif; margin: 0 auto; max-width: {PAGE_WIDTH_PX}px;
       padding: 0 12px; color: #222; }}
img {{ max-width: 100%; height: auto; display: block; }}
.tab {{ overflow-x: auto; max-width: 100%; }}
table {{ border-collapse: collapse; font-size: 13px; }}
td, th {{ border: 1px solid #bbb; padding: 3px 6px; text-align: right; }}
td:first-child, th:first-child {{ text-align: left; }}
.findings li {{ margin: 4px 0; }}
h1 {{ font-size: 22px; margin: 10px 0 6px; }}
ol.findings {{ font-size: 14px; margin: 6px 0 10px; padding-left: 22px; }}
details {{ border-top: 1px solid #ccc; padding: 4px 0; }}
details > summary {{ cursor: pointer; font-size: 18px; font-weight: bold; padding: 6px 0; }}
"""
OVERFLOW_PROBE = ("<script>addEventListener('load', function () {document.body.dataset.overflow"
                  " = String(document.documentElement.scrollWidth > innerWidth);});</script>")


def _pct(v) -> str:
    return "n/a" if v is None else f"{100 * v:.0f}%"


def _ident(e) -> str:
    i = e["identification"]
    return (f"{i['accuracy']:.2f} [{i['ci'][0]:.2f}, {i['ci'][1]:.2f}] "
            f"(n {i['n']})")


def findings_html(results) -> str:
    f = results["findings"]
    items = [html.escape(f["statement"])]
    for g in results["geometries"]:
        bg = f["by_geometry"][g["name"]]
        items.append(
            f"<b>{html.escape(g['name'])}</b> ({html.escape(g['description'])}; stroke / "
            f"measured lateral resolution {g['stroke_over_resolution']:.2f}): identification "
            f"{_pct(bg['identification_lambertian_and_diffuse'])} for Lambertian and "
            f"strong-diffuse materials, {_pct(bg['identification_specular_plus_diffuse'])} "
            f"for mixed, {_pct(bg['identification_strong_specular'])} for strong specular; "
            f"IoU above its box baseline by "
            f"{(bg['iou_excess_lambertian_and_diffuse'] or 0):+.2f} (diffuse) and "
            f"{(bg['iou_excess_strong_specular'] or 0):+.2f} (specular).")
    r = results["resolution"]
    items.append(
        f"Measured resolution at the seed geometry: effective temporal FWHM "
        f"{r['effective_temporal_fwhm_s'] * 1e12:.0f} ps after the deconvolution, O'Toole's "
        f"lateral bound {r['bound_lateral_m'] * 100:.1f} cm; "
        + ", ".join(f"{m} lateral {v['lateral_fwhm_m'] * 100:.1f} cm / axial "
                    f"{v['axial_fwhm_m'] * 100:.1f} cm" for m, v in r.items()
                    if isinstance(v, dict) and "lateral_fwhm_m" in v) + ".")
    items.append(
        f"No-reference metrics against identification (point-biserial r): nr_clarity "
        f"{f['corr_nr_clarity_vs_identified']:+.2f}, the seed's FFT clarity "
        f"{f['corr_clarity_vs_identified']:+.2f}; against IoU: FFT clarity "
        f"{f['corr_clarity_vs_iou_dataset']:+.2f}.")
    items.append("The legibility judge held out by " + "; ".join(
        f"{k}: balanced accuracy {v['balanced_accuracy']:.2f} (one feature "
        f"{v['baseline']:.2f}), AUC {v['auc']:.2f}, ECE {v['ece']:.3f}"
        for k, v in results["classifier"]["splits"].items()) + ".")
    seed_cnn = results.get("cnn_seed_recipe")
    if seed_cnn:
        items.append(
            f"The seed's CNN recipe ({html.escape(results['labels']['source'])} labels) on "
            f"held-out glyphs {', '.join(seed_cnn['held_out']['glyphs'])} and letters of "
            f"{seed_cnn['held_out']['letter_height_m']:g} m: accuracy "
            f"{seed_cnn['val_accuracy']:.2f} (majority class "
            f"{seed_cnn['majority_baseline']:.2f}, n {seed_cnn['n_val']}).")
    items.append(
        "Our labels agree with the seed's Figure 9 for "
        + ", ".join(f"{v} of 10 at {k}" for k, v in
                    results["seed_figure9_agreement_by_geometry"].items())
        + f" (the CNN's: {results['seed_figure9_agreement_cnn']}).")
    truth_cut = results.get("seed_figure9_agreement_truth_cut")
    if truth_cut:
        items.append(
            "These labels are cut at the quantiles of the seed's 193 / 514 / 293 split: their "
            "mix is the seed's by construction. Cut where they best match our ground truth "
            "instead, they agree for " + ", ".join(f"{v} of 10 at {k}" for k, v in
                                                   truth_cut.items()) + ".")
    for var, e in f["sweeps"].items():
        per = "; ".join(f"{html.escape(short_name(m, 22))} {v['min']:.2f}-{v['max']:.2f}"
                        for m, v in e["per_material"].items())
        items.append(f"{SWEEP_AXES.get(var, var)} (seed letters): identification spans "
                     f"{per}; change with the variable {e['geometry_effect']:.2f} against "
                     f"spread between materials {e['material_effect']:.2f}: "
                     f"<b>{e['dominant']}</b> dominates.")
    return "<ul class='findings'>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>"


def _acc(summary: dict | None) -> str:
    if summary is None:
        return "-"
    i = summary["identification"]
    return f"{i['accuracy']:.2f} [{i['ci'][0]:.2f}, {i['ci'][1]:.2f}]"


def _auto_lobes(m: dict) -> str:
    """The half widths (deg) of the lobes "auto" chose for a material's glyphs: their median
    and range."""
    a = m.get("inversions", {}).get("auto")
    if not a:
        return "-"
    w = np.asarray(a["lobe_halfwidth_deg"], float)
    return f"{np.median(w):.2g} ({w.min():.2g}-{w.max():.2g})"


def _geometry_table(g) -> str:
    invs = [inv for inv in ("known", "auto") if any(inv in m.get("inversions", {})
                                                    for m in g["materials"])]
    rows = [[html.escape(m["name"]), html.escape(m["brdf_class"]),
             f"{m['specular_fraction']:.2f}",
             f"{m['measurement_identification']['accuracy']:.2f}", _ident(m),
             *[_acc(m.get("inversions", {}).get(inv)) for inv in invs],
             *([_auto_lobes(m)] if "auto" in invs else []),
             f"{m['identification']['chance']:.3f}", f"{m['iou']:.3f}",
             f"{m['iou_box_baseline']:.3f}", f"{m['iou_excess']:+.3f}",
             f"{m['depth_error_m'] * 100:.1f}", f"{m['photon_counts']:.2g}", m["label"],
             m["cnn_label"], m["seed_label"] if m["seed_label"] is not None else "-",
             m["clarity_label"]] for m in g["materials"]]
    head = (f"<p>Geometry <b>{html.escape(g['name'])}</b>: {html.escape(g['description'])};"
            f" scan {g['scan_width_m']} m, letters {g['letter_height_m']} m tall with "
            f"{g['stroke_m'] * 100:g} cm strokes at {g['depth_m']} m; measured lateral "
            f"resolution {g['lateral_resolution_m'] * 100:.1f} cm, stroke / resolution "
            f"{g['stroke_over_resolution']:.2f}. Identification [Wilson 95%] of the "
            "measurement alone (time-integrated, no reconstruction) and of the iterative "
            "inversion with each reflectance; IoU and the labels are the Lambertian "
            "inversion's.</p>")
    return head + _table(["material", "BRDF class", "specular fraction", "measurement alone",
                          "Lambertian [95%]",
                          *[f"{INVERSION_LABELS[inv]} [95%]" for inv in invs],
                          *(["auto lobe half width (deg)"] if "auto" in invs else []),
                          "chance", "IoU",
                          "box baseline IoU",
                          "IoU - baseline", "depth error (cm)", "photons", "label",
                          "CNN label", "seed Fig. 9", "FFT label"], rows)


def _tilt_html(results) -> str:
    rows = results.get("tilt_sweep") or []
    if not rows:
        return "<p>No tilt sweep in this run.</p>"
    cols = [c for c in (*results.get("inversions", ("lambertian",)), "measurement")
            if c in rows[0]]
    body = [[html.escape(r["material"]), f"{r['tilt_deg']:g}",
             f"{r['mirror_shift_m'] * 100:.1f}",
             *[f"{r[c]['identification']['accuracy']:.2f} ({r[c]['shift_m'] * 100:.1f} cm)"
               for c in cols]] for r in rows]
    gap = results["findings"].get("tilt", {}).get("worst_gap_below_measurement")
    text = ("<p>Glyphs tilted about the y axis at the legible geometry, matched to the K "
            "templates up to a translation of "
            f"{results['tilt_max_shift_m'] * 100:g} cm; beside each "
            "identification, the mean displacement of the true glyph's best match. A mirror "
            "returns light about z tan(tilt) away from the glyph: a confocal scan cannot tell "
            "a tilted glyph with a sharp lobe from a displaced one.")
    if gap:
        text += (f" Largest gap of the best inversion below the measurement alone: "
                 f"{gap['gap']:+.2f} ({html.escape(gap['material'])}, {gap['tilt_deg']:g} "
                 "deg).")
    return text + "</p>" + _table(["material", "tilt (deg)", "z tan(tilt) (cm)",
                                   *[INVERSION_LABELS.get(c, c) for c in cols]], body)


def _real_html(results) -> str:
    rc = results.get("real_capture")
    if not rc:
        return ("<p>No real capture: run the study with <code>--real-data DIR</code>, the "
                "folder whose <code>cdt/</code> holds the real CDT captures.</p>")
    keys = ("photons", "peak_time_s", "temporal_fwhm_s")
    rows = [[k, f"{rc[k]:.4g}", f"{rc['simulated'][k]:.4g}",
             f"{rc['simulated'][k] / rc[k]:.3g}" if rc[k] else "-"] for k in keys]
    out = _table(["quantity", f"real ({html.escape(rc['name'])})", "simulated",
                  "simulated / real"], rows)
    if rc.get("differences"):
        out += ("<p>What the simulation gets wrong:</p><ul>" + "".join(
            f"<li>{html.escape(d)}</li>" for d in rc["differences"]) + "</ul>")
    chart = results["resolution"].get("real_chart")
    if chart:
        feats = chart.get("features", {})
        out += (f"<p>The real resolution chart ({html.escape(chart['name'])}, "
                f"{html.escape(chart['method'])}, published settings): "
                f"{sum(bool(f['resolved']) for f in feats.values())} of {len(feats)} "
                f"features resolved ({html.escape(str(chart.get('criterion', '')))}).</p>")
        out += _table(["feature", "spacing (cm)", "contrast", "resolved"],
                      [[html.escape(k), "-" if f.get("spacing_m") is None
                        else f"{f['spacing_m'] * 100:.1f}",
                        "-" if f.get("contrast") is None else f"{f['contrast']:.2f}",
                        "yes" if f["resolved"] else "no"] for k, f in feats.items()])
    cnn = results.get("real_captures_cnn") or []
    if cnn:
        out += "<p>The CNN's verdict on the real captures (all their photons, reconstructed " \
               "with the study's method and defaults):</p>" + _table(
                   ["capture", "P(legible)", "CNN label", "probabilities"],
                   [[html.escape(c["name"]), f"{c['p_legible']:.3f}", c["cnn_label"],
                     ", ".join(f"{p:.2f}" for p in c["cnn_probabilities"])] for c in cnn])
    return out


def _transport_section(comparison) -> list[str]:
    """The material table under both transports (``--transport both``, the ``--full``
    default), else a paragraph saying it was not run and how to run it."""
    title = "The material table under both transports: does Eq. 9 change the ranking?"
    if not comparison:
        return [f"<h3>{html.escape(title)}</h3>",
                "<p>Not run in this report: every sample here was simulated with the "
                "seed's confocal transport (Eq. 9: light leaves and re-enters the slab's "
                "face at one point, the BRDF read on its retro slice). <code>clnlos study "
                "--transport both</code> (the <code>--full</code> default) renders the "
                "materials at the legible geometry under Eq. 8 in full too and tabulates "
                "identification, margins and ranks under each.</p>"]
    return [f"<h3>{html.escape(title)}</h3>",
            comparison_html(comparison, comparison["face_rings"], comparison["face_angles"]),
            f"<img alt='{html.escape(title)}' src='data:image/png;base64,"
            f"{png_base64(fig_transport(comparison))}'/>"]


def _reconstruction_detail(grid: dict) -> str:
    """The study's reconstruction settings for the setup line: the iterations (iterative
    method) and the rule its "auto" SNRs came from: StudyGrid.snr_rule where it is valid
    for the method, else the method's own "auto" (:func:`clnlos.config.snr_rule_applies`,
    as the samples are reconstructed)."""
    method, rule = grid["method"], grid.get("snr_rule", "gcv")
    if not snr_rule_applies(rule, method):
        auto = auto_snr_rule(method)
        rule = "auto (gcv)" if auto == "gcv" else f"auto ({auto} on counts of the slab simulated)"
    text = f"SNRs by {rule}"
    return f"{grid['iterations']} iterations, {text}" if method == "iterative" else text


def _cost_html(results) -> list[str]:
    """The cost table: each stage's wall time, then per part of the plan its distinct
    samples and the seconds they took to simulate and reconstruct (summed over workers)."""
    cost = results.get("cost")
    t = results["timings_s"]
    out = ["<h3>Each stage</h3>",
           _table(["stage", "wall time (s)"],
                  [[k.removesuffix("_s"), f"{v:.1f}"] for k, v in t.items()])]
    if cost is None:
        return out
    rows = [[p["part"], p["entries"], p["samples"], f"{p['simulate_s']:.1f}",
             f"{p['reconstruct_s']:.1f}",
             f"{(p['simulate_s'] + p['reconstruct_s']) / max(p['samples'], 1):.2f}"]
            for p in cost["parts"]]
    out.append("<p>Samples per part of the study (a sample two parts ask for is rendered "
               "once, counted where first asked for); seconds summed over the workers, as "
               "recorded when each sample was rendered (0 for none: all from the cache).</p>")
    out.append(_table(["part", "entries", "samples rendered", "simulate (s)",
                       "reconstruct (s)", "per sample (s)"], rows))
    return out


def _section(title: str, parts, open_: bool = False) -> str:
    """A section the reader folds: ``<details>`` with ``title`` as its summary."""
    return (f"<details{' open' if open_ else ''}><summary>{html.escape(title)}</summary>"
            + "\n".join(parts) + "</details>")


def _figure(title: str, caption: str, fig) -> list[str]:
    out = [f"<h3>{html.escape(title)}</h3>"] + ([f"<p>{html.escape(caption)}</p>"]
                                               if caption else [])
    src = f"data:image/png;base64,{png_base64(fig)}"
    return out + [f"<img alt='{html.escape(title)}' src='{src}'/>"]


def _setup_line(results) -> str:
    """The rig and the reconstruction, as the study file gave them."""
    g = results["options"]["grid"]
    slab = ("no slab" if g["slab"] is None else
            f"{100 * g['slab'][0]:.3g} cm slab (mu_a {g['slab'][1]:g} 1/m, mu_s' "
            f"{g['slab'][2]:g} 1/m, n {g['slab'][3]:g})")
    pulse = ("no pulse blur" if g["pulse_width_s"] is None
             else f"{g['pulse_width_s'] * 1e12:.0f} ps pulse")
    recon = ", ".join(f"{m} ({_reconstruction_detail({**g, 'method': m})})"
                      for m in results["options"]["methods"])
    return (f"<p>Study <b>{html.escape(results['study'])}</b>"
            + (f" ({html.escape(results['source'])})" if results.get("source") else "")
            + f": {g['points']} x {g['points']} scan points over {g['scan_width_m']:g} m "
            f"(targets may name their own), {g['bin_width_s'] * 1e12:.3g} ps bins, {slab}, "
            f"{pulse}, {g['rep_rate_hz'] / 1e6:.3g} MHz, {g['power_w'] * 1e3:.3g} mW at "
            f"{g['wavelength_m'] * 1e9:.0f} nm, detector efficiency {g['efficiency']:g}, "
            f"etendue {g['etendue_m2_sr']:.3g} m^2 sr, dark counts "
            f"{g['dark_count_rate_hz']:g} /s; {g['exposure_s']:g} s per scan point unless "
            f"swept; reconstruction: {recon}; {results['options']['realisations']} noise "
            f"realisation(s) per point unless a sweep says otherwise; {results['n_dataset']} "
            "reconstructions in all.</p>")


def _need_table(results) -> str:
    def need(n, var):
        if n[var] is None:
            return "-"
        via = n.get(f"{var}_inversion")
        return f"{n[var]:g}" + (f" ({INVERSION_LABELS.get(via, via)})" if via else "")

    rows = [[html.escape(n["material"]),
             html.escape(INVERSION_LABELS.get(n.get("inversion", "lambertian"),
                                              n.get("inversion", ""))),
             need(n, "letter_height_m"), need(n, "exposure_s")]
            for n in results["smallest_legible"]]
    o = results["options"]
    return (f"<p>Legible geometry; identification >= {o['legible_fraction']:g} at "
            f"{o['grid']['exposure_s']:g} s per point (height) and at the target's own letter "
            "height (exposure); '-': not reached within the swept values; a value "
            "equal to the smallest swept one is an upper bound (the smallest tried).</p>"
            + _table(["material", "inversion", "smallest legible letter (m)",
                      "exposure needed (s)"], rows))


def _resolution_html(results) -> str:
    r = results["resolution"]
    rows = [[m, f"{v['lateral_fwhm_m'] * 100:.2f}", f"{v['axial_fwhm_m'] * 100:.2f}"]
            for m, v in r.items() if isinstance(v, dict) and "lateral_fwhm_m" in v]
    return (_table(["method", "lateral FWHM (cm)", "axial FWHM (cm)"], rows)
            + f"<p>O'Toole's bound with the measured effective temporal FWHM "
            f"{r['effective_temporal_fwhm_s'] * 1e12:.0f} ps: "
            f"{r['bound_lateral_m'] * 100:.2f} cm.</p>")


def _metrics_html(results) -> str:
    val = results["metric_validation"]
    rows = [[m + (" (labels)" if m == results["labels"]["metric"] else ""),
             f"{val[m]['identified']:+.2f}", f"{val[m]['iou']:+.2f}",
             f"{val[m]['iou_excess']:+.2f}", f"{val[m]['depth_error_m']:+.2f}",
             f"{val[m]['psnr_db']:+.2f}"] for m in METRICS]
    return ("<p>Pearson r over the glyph reconstructions (point-biserial for identified).</p>"
            + _table(["metric", "r with identified", "r with IoU", "r with IoU - baseline",
                      "r with depth error", "r with PSNR"], rows))


def real_materials_html(results, out_dir) -> list[str]:
    """The real materials' section (``results["real_materials"]``, built by
    :mod:`clnlos.study.real.materials`) when the study made one."""
    section = results.get("real_materials")
    if section:
        return [real_materials.section_html(section, out_dir, png_base64)]
    return []


def write_report(out_dir, results, plan, res, real=None, checks=None) -> None:
    """report.html: the answer first (:func:`headline_html`), then the plan's table and
    reconstructions, the real captures beside their twins, the material table's sections
    where the study has one, the materials, the setup and the cost."""
    import matplotlib

    matplotlib.use("Agg")
    title = ("How the surface material of a hidden target changes what we can read"
             if results.get("geometries") else
             f"Exposure needed: {html.escape(results['study'])}")
    body = [f"<h1>{title}</h1>", headline_html(results, png_base64)]
    body += plan_sections(results, plan, res)
    if results.get("real_check"):
        body.append(_section("Real captures of the rig beside their twins",
                             real_check_html(results, checks, _table, png_base64), open_=True))
    if results.get("geometries"):
        body += table_sections(results, plan, res, real, out_dir)
    elif results.get("real_materials"):
        body += real_materials_html(results, out_dir)
    body += [_section("Materials and setup", [_materials_html(results), _setup_line(results)]),
             _section("Where the time goes", _cost_html(results))]
    with atomic_path(out_dir / "report.html") as tmp:
        tmp.write_text(page_html(body), encoding="utf-8")


def plan_sections(results, plan, res) -> list[str]:
    """The plan's table, what was left out, the reconstructions around the threshold, the
    smallest legible letters, the other sweeps."""
    out = []
    if results.get("plan"):
        parts = [plan_table(results["plan"], _table)]
        if results.get("left_out"):
            parts.append("<p>Left out (a method cannot assume that reflectance): "
                         + "; ".join(html.escape(n) for n in results["left_out"]) + ".</p>")
        if results.get("geometries"):  # the first screen holds the table's panel instead
            parts += _figure("The curves the exposure needed comes from",
                             "Share of legible realisations (Wilson 95%) against exposure "
                             "per scan point; lines: the non-decreasing fit; dashed: the "
                             "legible level.", fig_curves(results))
        gallery = fig_threshold_gallery(results, plan, res)
        if gallery is not None:
            parts += _figure("Reconstructions along each curve (first realisation; green "
                             "frame: the fitted share reaches the legible level)",
                             "Front views (max over depth, normalised); title: exposure per "
                             "scan point, legible realisations / all.", gallery)
        out.append(_section("The exposure needed, row by row", parts, open_=True))
    letters = [L for L in results.get("smallest_legible_letter", ())]
    if letters:
        rows = [[html.escape(L["target"]), html.escape(L["material"]),
                 html.escape(f"{L['method']} {L['reflectance']}"), f"{L['exposure_s']:g}",
                 "none" if L["letter_height_m"] is None else f"{100 * L['letter_height_m']:.3g}",
                 ", ".join(f"{100 * h:.3g}: {f:.2f}" for h, f in zip(
                     L["heights_m"], L["fractions"], strict=True))] for L in letters]
        out.append(_section("The smallest legible letter", [_table(
            ["target", "material", "inversion", "exposure per point (s)",
             "smallest legible (cm)", "height (cm): share legible"], rows)]))
    return out


def table_sections(results, plan, res, real, out_dir) -> list[str]:
    """The material table's sections (the seed's question)."""
    legible, seed = results["legible_geometry"], results["seed_geometry"]
    return [
        "<h2>The seed's Figure 8, side by side (legible geometry)</h2>",
        "<p>Per material: the measurement (photon counts) integrated over time with its x-t "
        "and y-t slices, the Lambertian reconstruction's MIP with the true outline (red) and "
        "its x-z and y-z projections (dotted: the true depth), and the MIP of the inversion "
        "with the material's own BRDF.</p>",
        f"<img alt='the seed Figure 8 side by side' src='data:image/png;base64,"
        f"{png_base64(fig_figure8(results, plan, res, legible))}'/>",
        _section("All findings in numbers", [findings_html(results), _setup_line(results)]),
        _section("Materials at each geometry", [
            *[_geometry_table(geo) for geo in results["geometries"]],
            *_figure("Identification and IoU against the blob baseline", "",
                     fig_identification(results)),
            *_figure("Every glyph at the legible geometry", "Title: true glyph -> the "
                     "matched one.", fig_materials(results, plan, res, legible)),
            *(_figure("Every glyph at the seed's Table 1 geometry", "Title: true glyph -> "
                      "the matched one.", fig_materials(results, plan, res, seed))
              if seed != legible else [])]),
        _section("What the material costs: letter size and exposure", [
            _need_table(results),
            *_figure("Letter size and exposure", "Legible geometry; mean over glyphs and "
                     "noise realisations, Wilson 95% intervals.",
                     fig_legibility_sweeps(results))]),
        _section("Tilted glyphs: identification up to a translation", [
            _tilt_html(results), *(_figure("Tilted glyphs (legible geometry)",
                                           "Identification up to a translation; dotted: "
                                           "the measurement alone.", fig_tilt(results))
                                   if results.get("tilt_sweep") else [])]),
        _section("Geometry sweeps (the seed's letters)", _figure("Geometry sweeps", "",
                                                                   fig_sweeps(results))
                 if results.get("sweeps") else ["<p>No geometry sweep in this study.</p>"]),
        *real_materials_html(results, out_dir),
        _section("A real capture and its simulation", [
            _real_html(results), *(_figure("A real capture beside its simulation", "",
                                           real["figure"])
                                   if real is not None and real.get("figure") is not None
                                   else [])]),
        _section("The legibility judge", classifier_section(
            results, None if real is None else real.get("thinning"), _table, png_base64,
            None if real is None else [r for r in real.get("family") or () if "mip" in r])),
        _section("The material table under both transports",
                 _transport_section(results.get("transport_comparison"))),
        _section("Methods: resolution, metrics, BRDFs", [
            "<h3>Measured resolution (seed geometry, noise-free point target)</h3>",
            _resolution_html(results),
            "<h3>No-reference metrics against ground truth</h3>", _metrics_html(results),
            *_figure("No-reference metrics against ground truth", "",
                     fig_metrics(results, plan, res)),
            *(_figure("The seed's CNN recipe (seed Fig. 9)", "", fig_cnn(results))
              if results.get("cnn_seed_recipe") else []),
            *_figure("BRDF of each material (seed Fig. 7)", "", fig_brdf(results))])]


def _materials_html(results) -> str:
    """Each material: its BRDF, albedo, class, and what was made of a file (a measured
    BRDF's fit with every candidate's held-out agreement)."""
    rows = []
    for m in results.get("materials_prepared", ()):
        fit = m.get("fit")
        fit_txt = "" if not fit else (
            f"{fit['model']}: held-out agreement {fit['agreement_pct']:.1f}%, peak error "
            f"{fit['peak_error_pct']:+.0f}%" + ("" if m.get("fit_usable") else
                                                 " (not usable: approximate)")
            + ("; candidates " + ", ".join(f"{k} {v['agreement_pct']:.0f}%"
                                           for k, v in fit["candidates"].items())
               if fit.get("candidates") else ""))
        rows.append([html.escape(m["name"]), html.escape(str(m["brdf"])), f"{m['albedo']:g}",
                     html.escape(m["brdf_class"]), html.escape(fit_txt)])
    return _table(["material", "BRDF", "albedo", "class", "fit of a measured BRDF"], rows)


def page_html(body: list[str]) -> str:
    """The report's page around ``body`` (its style, the layout probes)."""
    return (f"<!doctype html><html><head><meta charset='utf-8'>{HTML_GENERATOR}"
            "<meta name='viewport' content='width=device-width, initial-scale=1'>"
            f"<title>clnlos material study</title><style>{STYLE}</style>{OVERFLOW_PROBE}"
            f"{probe_script()}</head><body>" + "\n".join(body) + "</body></html>")


def comparison_html(comparison: dict, rings: int, angles: int) -> str:
    """The report's section body: how it was made, the table, the statement."""
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
        + f"<p>Rank correlation: Spearman {fmt_r(c['rank']['spearman'])}, Kendall "
        f"{fmt_r(c['rank']['kendall'])}; of the accuracies: Spearman "
        f"{fmt_r(c['accuracy']['spearman'])}, Kendall {fmt_r(c['accuracy']['kendall'])}; of "
        f"the margins: Spearman {fmt_r(c['margin']['spearman'])}, Kendall "
        f"{fmt_r(c['margin']['kendall'])}.</p>"
        f"<p><b>{html.escape(comparison['statement'])}</b></p>"
        "<p>Regenerate: <code>python -m clnlos study --transport both</code> (this section; "
        "adds 80 bistatic samples to the quick study, about 8 s each on 2 cores) or <code>python "
        "tools/study_transport.py</code> (the table alone, "
        "tools/results/study_transport.{csv,json}).</p>")

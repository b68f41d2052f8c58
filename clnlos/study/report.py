"""The study report: one self-contained HTML page (PNG figures embedded) beside results.json.

Laid out for a 1280 px browser window: a fixed-width column, tables that scroll inside their
own box, figures scaled to the column. Every figure has axes with units and, for images, a
colour bar. A script marks the page's body with ``data-overflow`` (whether anything is wider
than the window), which tools/check_report.py reads in headless Chromium.
"""

from __future__ import annotations

import base64
import html
import io

import numpy as np

from clnlos import C0
from clnlos.brdf.models import retro_slice
from clnlos.brdf.presets import preset_model
from clnlos.config import snr_rule_applies
from clnlos.inverse.methods import auto_snr_rule
from clnlos.io.files import atomic_path
from clnlos.io.outputs import HTML_GENERATOR
from clnlos.study.classifier_report import classifier_section
from clnlos.study.quality import METRICS
from clnlos.study.transport_compare import TRANSPORTS, fmt_r

PAGE_WIDTH_PX = 1180
DPI = 100


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _short(name: str, n: int = 16) -> str:
    return name if len(name) <= n else name[:n - 1] + "."


def _outline(ax, truth, w):
    c = np.linspace(-w / 2, w / 2, truth.shape[0] + 1)
    cc = (c[:-1] + c[1:]) / 2
    ax.contour(cc, cc, truth, [0.5], colors="tab:red", linewidths=0.8)


def _first_sample(plan, res, geometry: str, material: str, glyph: str | None = None,
                  inversion: str = "lambertian"):
    for (meta, s), r in zip(plan, res, strict=True):
        if (meta["set"] == "main" and meta["geometry"] == geometry
                and meta["material"] == material and meta["k"] == 0
                and meta.get("inversion", "lambertian") == inversion
                and (glyph is None or meta["glyph"] == glyph)):
            return s, r
    return None, None


INVERSION_LABELS = {"lambertian": "Lambertian", "known": "known BRDF", "auto": "BRDF auto",
                    "measurement": "measurement alone"}


def fig_materials(results, plan, res, geometry: str):
    """Each material's reconstruction of every glyph's first realisation (MIP, true outline
    in red, the matched glyph in the title)."""
    import matplotlib.pyplot as plt

    geo = next(g for g in results["geometries"] if g["name"] == geometry)
    glyphs = results["options"]["glyphs"]
    mats = geo["materials"]
    w = geo["scan_width_m"]
    fig, axes = plt.subplots(len(mats), len(glyphs), figsize=(11.5, 1.45 * len(mats) + 0.6),
                             squeeze=False, constrained_layout=True)
    ext = (-w / 2, w / 2, -w / 2, w / 2)
    im = None
    for i, m in enumerate(mats):
        for j, g in enumerate(glyphs):
            ax = axes[i, j]
            _, r = _first_sample(plan, res, geometry, m["name"], g)
            im = ax.imshow(r["mip"], origin="lower", cmap="gray", extent=ext, vmin=0, vmax=1)
            _outline(ax, r["truth"], w)
            ok = "ok" if r["identified"] else "no"
            ax.set_title(f"{g} -> {r['identified_as']} ({ok})", fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(_short(m["name"], 18), fontsize=7)
    axes[-1, 0].set_xticks([-w / 2, 0, w / 2])
    axes[-1, 0].set_xlabel("x (m)", fontsize=7)
    fig.colorbar(im, ax=axes, shrink=0.5, label="MIP / max (a.u.)")
    return fig


def fig_figure8(results, plan, res, geometry: str):
    """The seed's Figure 8 side by side, per material (glyph E, first realisation): the
    measurement integrated over time with its x-t and y-t slices through the scan centre,
    and the reconstruction's MIP (true outline in red) with its x-z and y-z projections."""
    import matplotlib.pyplot as plt

    geo = next(g for g in results["geometries"] if g["name"] == geometry)
    mats = geo["materials"]
    w = geo["scan_width_m"]
    glyph = results["options"]["glyphs"][0]
    aware = next((inv for inv in ("known", "auto") if inv in results.get("inversions", ())),
                 None)
    ncol = 7 if aware else 6
    fig, axes = plt.subplots(len(mats), ncol, figsize=(11.5, 1.75 * len(mats) + 0.8),
                             squeeze=False, constrained_layout=True)
    titles = ("measurement, sum over t", "x-t (y = 0)", "y-t (x = 0)",
              "Lambertian MIP", "x-z (max over y)", "y-z (max over x)",
              f"{INVERSION_LABELS.get(aware, '')} MIP")
    for i, m in enumerate(mats):
        _, r = _first_sample(plan, res, geometry, m["name"], glyph)
        _, ra = (None, None) if aware is None else _first_sample(plan, res, geometry,
                                                                 m["name"], glyph, aware)
        nt = r["meas_xt"].shape[0]
        t_ns = nt * r["bin_width_s"] * 1e9
        nz = r["vol_xz"].shape[0]
        z_max = nz * r["voxel_depth_m"]
        ext_xy = (-w / 2, w / 2, -w / 2, w / 2)
        panels = ((r["meas_image"], ext_xy, "magma"),
                  (r["meas_xt"], (-w / 2, w / 2, 0, t_ns), "magma"),
                  (r["meas_yt"], (-w / 2, w / 2, 0, t_ns), "magma"),
                  (r["mip"], ext_xy, "gray"),
                  (r["vol_xz"], (-w / 2, w / 2, 0, z_max), "gray"),
                  (r["vol_yz"], (-w / 2, w / 2, 0, z_max), "gray"))
        if ra is not None:
            panels += ((ra["mip"], ext_xy, "gray"),)
        for j, (img, ext, cmap) in enumerate(panels):
            ax = axes[i, j]
            a = np.asarray(img, float)
            a = a / a.max() if a.max() > 0 else a
            im = ax.imshow(a, origin="lower", aspect="auto", extent=ext, cmap=cmap,
                           vmin=0, vmax=1)
            if j == 0:
                first = im
            if j in (3, 6):
                _outline(ax, r["truth"], w)
            if j in (4, 5):
                ax.axhline(geo["depth_m"], color="tab:red", lw=0.6, ls=":")
            ax.tick_params(labelsize=6)
            if i == 0:
                ax.set_title(titles[j], fontsize=8)
            if i == len(mats) - 1:
                ax.set_xlabel("x (m)" if j in (0, 1, 3, 4, 6) else "y (m)", fontsize=7)
            ax.set_ylabel({0: f"{_short(m['name'], 16)}\ny (m)", 1: "t (ns)", 2: "t (ns)",
                           3: "y (m)", 4: "z (m)", 5: "z (m)", 6: "y (m)"}[j], fontsize=7)
        if i == 0:
            fig.colorbar(first, ax=axes[:, 0], shrink=0.3, location="left",
                         label="counts / max")
            fig.colorbar(im, ax=axes[:, ncol - 1], shrink=0.3, label="/ max (a.u.)")
    fig.suptitle(f"glyph {glyph}, geometry {geometry}: {geo['description']} "
                 f"(c t / 2 at the window end: {C0 * t_ns * 1e-9 / 2:.2f} m)", fontsize=8)
    return fig


def fig_identification(results):
    """Identification accuracy per material and geometry (Wilson 95% intervals, chance), and
    IoU against the box baseline."""
    import matplotlib.pyplot as plt

    geos = results["geometries"]
    fig, ax = plt.subplots(1, 2, figsize=(11.5, 4.2), constrained_layout=True)
    names = [m["name"] for m in geos[0]["materials"]]
    x = np.arange(len(names))
    width = 0.8 / len(geos)
    for k, g in enumerate(geos):
        acc = np.array([m["identification"]["accuracy"] for m in g["materials"]])
        ax[0].bar(x + (k - (len(geos) - 1) / 2) * width, acc, width,
                  yerr=_ci_err(acc, g["materials"]),
                  capsize=2, label=f"{g['name']} (stroke/res {g['stroke_over_resolution']:.1f})")
        box = [m["iou_box_baseline"] for m in g["materials"]]
        ax[1].scatter(box, [m["iou"] for m in g["materials"]], label=g["name"], s=18)
    chance = geos[0]["materials"][0]["identification"]["chance"]
    ax[0].axhline(chance, color="gray", ls=":", label=f"chance 1/K = {chance:.3f}")
    ax[0].set_xticks(x)
    ax[0].set_xticklabels([_short(n, 18) for n in names], rotation=55, ha="right",
                          fontsize=7)
    ax[0].set(ylabel="identification accuracy (95% Wilson interval)", ylim=(0, 1.05),
              title="which of K glyphs? (closest blurred template)")
    ax[0].legend(fontsize=7)
    ax[1].plot([0, 1], [0, 1], color="gray", ls=":", label="IoU = box baseline")
    ax[1].set(xlabel="IoU of the filled box of the true mask (blob baseline)",
              ylabel="IoU of the reconstruction", xlim=(0, 1), ylim=(0, 1),
              title="IoU against what a blob scores")
    ax[1].legend(fontsize=7)
    return fig


def fig_legibility_sweeps(results):
    import matplotlib.pyplot as plt

    rows = results["legibility_sweeps"]
    fig, ax = plt.subplots(1, 2, figsize=(11.5, 3.8), constrained_layout=True)
    for a, var, xlabel in ((ax[0], "letter_height_m", "letter height (m; strokes scaled)"),
                           (ax[1], "exposure_s", "exposure per scan point (s)")):
        for m, x, y, err, rs in _sweep_series(rows, var):
            fmt = "o-" if rs[0].get("inversion", "lambertian") == "lambertian" else "s--"
            a.errorbar(x, y, yerr=err, fmt=fmt, capsize=3, label=_short(m, 36))
        a.axhline(0.9, color="gray", ls="--", lw=0.8, label="legible (0.9)")
        if rows:
            a.axhline(rows[0]["identification"]["chance"], color="gray", ls=":", lw=0.8,
                      label="chance")
        if var == "exposure_s":
            a.set_xscale("log")
        a.set(xlabel=xlabel, ylabel="identification accuracy", ylim=(0, 1.05))
        a.legend(fontsize=7)
    return fig


def fig_brdf(results):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11.5, 3.8), constrained_layout=True)
    ts = np.radians(np.linspace(-89, 89, 357))
    for m in results["materials"]:
        model = preset_model(m["name"])
        ax[0].semilogy(np.linspace(0, 90, 91), np.maximum(retro_slice(model, 91), 1e-4),
                       label=_short(m["name"], 22))
        f = model(np.full_like(ts, np.pi / 4), 0 * ts, np.abs(ts), np.where(ts >= 0, np.pi, 0))
        ax[1].semilogy(np.degrees(ts), np.maximum(f, 1e-4))
    ax[0].set(xlabel="angle to the surface normal (deg)", ylabel="BRDF f(w, w) (1/sr)",
              title="confocal retro-reflection slice (what the scan sees)")
    ax[1].set(xlabel="outgoing angle theta_s (deg, + = forward)", ylabel="BRDF (1/sr)",
              title="in-plane slice at theta_i = 45 deg")
    ax[0].legend(fontsize=6, ncol=2)
    return fig


def fig_metrics(results, plan, res):
    """No-reference metrics against ground truth over the glyph reconstructions: each
    metric against IoU, coloured by whether the glyph was identified."""
    import matplotlib.pyplot as plt

    rs = [r for (meta, _), r in zip(plan, res, strict=True) if meta["set"] != "dataset"]
    iou = np.array([r["iou"] for r in rs])
    ok = np.array([r["identified"] for r in rs])
    fig, ax = plt.subplots(1, 3, figsize=(11.5, 3.6), constrained_layout=True)
    ax[0].hist([iou[ok], iou[~ok]], bins=20, range=(0, 1), stacked=True,
               label=["identified", "not identified"], color=["tab:green", "tab:red"])
    ax[0].set(xlabel="IoU of the MIP", ylabel="reconstructions",
              title=f"glyph reconstructions (n = {len(rs)})")
    ax[0].legend(fontsize=7)
    val = results["metric_validation"]
    for a, name in ((ax[1], "nr_clarity"), (ax[2], "fft_clarity")):
        v = np.array([r[f"q_{name}"] for r in rs])
        a.scatter(v[ok], iou[ok], s=6, c="tab:green", label="identified")
        a.scatter(v[~ok], iou[~ok], s=6, c="tab:red", label="not identified")
        a.set(xlabel=name + (" (log10)" if name == "fft_clarity" else " (0..1)"),
              ylabel="IoU", title=f"{name}: r = {val[name]['iou']:+.2f} with IoU,\n"
                                  f"{val[name]['identified']:+.2f} with identified")
        a.legend(fontsize=7)
    return fig


def fig_cnn(results):
    """The seed recipe's CNN (``--labels fft`` / ``nr``): confusion, loss, accuracy."""
    import matplotlib.pyplot as plt

    cnn = results["cnn_seed_recipe"]
    fig, ax = plt.subplots(1, 3, figsize=(11.5, 3.5), constrained_layout=True)
    conf = np.asarray(cnn["confusion"])
    k = conf.shape[0]
    im = ax[0].imshow(conf, cmap="Blues")
    for i in range(k):
        for j in range(k):
            ax[0].text(j, i, str(conf[i, j]), ha="center", va="center")
    names = [str(i + 1) for i in range(k)]
    ax[0].set(xticks=range(k), yticks=range(k), xticklabels=names,
              yticklabels=names, xlabel="CNN label", ylabel="true label",
              title=f"validation: accuracy {cnn['val_accuracy']:.2f} "
                    f"(majority {cnn['majority_baseline']:.2f})")
    fig.colorbar(im, ax=ax[0], label="samples")
    ep = np.arange(1, len(cnn["train_loss"]) + 1)
    ax[1].plot(ep, cnn["train_loss"], "o-", label="training")
    ax[1].plot(ep, cnn["val_loss"], "s-", label="validation")
    ax[1].set(xlabel="epoch", ylabel="cross-entropy loss", title="loss")
    ax[1].legend()
    ax[2].plot(ep, cnn["train_accuracy"], "o-", label="training")
    ax[2].plot(ep, cnn["val_accuracy_per_epoch"], "s-", label="validation")
    ax[2].axhline(cnn["majority_baseline"], color="gray", ls=":", label="majority class")
    ax[2].set(xlabel="epoch", ylabel="accuracy", ylim=(0, 1), title="accuracy")
    ax[2].legend()
    return fig


SWEEP_AXES = {"scan_width_m": "scan width (m)", "depth_m": "target depth (m)",
              "slab_thickness_m": "slab thickness (m; 0 = no slab)"}


def sweep_condition(variable: str, value: float) -> str:
    """'without the slab', 'at a target depth of 0.9 m', ... for a sweep point."""
    if variable == "slab_thickness_m":
        return "without the slab" if value == 0 else f"behind a {value * 100:g} cm slab"
    name = SWEEP_AXES.get(variable, variable).split(" (")[0]
    return f"at a {name} of {value:g} m"


def fig_sweeps(results):
    """The geometry sweeps at the seed's letter size: identification (top) and IoU over its
    box baseline (bottom) against each variable."""
    import matplotlib.pyplot as plt

    rows = results["sweeps"]
    variables = list(dict.fromkeys(r["variable"] for r in rows))
    fig, ax = plt.subplots(2, len(variables), figsize=(11.5, 6.4), squeeze=False,
                           constrained_layout=True)
    for j, var in enumerate(variables):
        for m, x, y, err, rs in _sweep_series(rows, var):
            ax[0, j].errorbar(x, y, yerr=err, fmt="o-", capsize=3, label=_short(m, 22))
            ax[1, j].plot(x, [r["iou_excess"] for r in rs], "o-", label=_short(m, 22))
        ax[0, j].axhline(rows[0]["identification"]["chance"], color="gray", ls=":", lw=0.8)
        ax[0, j].set(xlabel=SWEEP_AXES.get(var, var), ylabel="identification accuracy",
                     ylim=(0, 1.05))
        ax[1, j].axhline(0, color="gray", ls=":", lw=0.8)
        ax[1, j].set(xlabel=SWEEP_AXES.get(var, var), ylabel="IoU - box baseline IoU")
        ax[0, j].legend(fontsize=7)
    return fig


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
"""
OVERFLOW_PROBE = ("<script>addEventListener('load', function () {document.body.dataset.overflow"
                  " = String(document.documentElement.scrollWidth > innerWidth);});</script>")


def _ci_err(values, rows, key="identification"):
    """errorbar's [below, above] of each row's 95% interval around ``values`` (never < 0)."""
    y = np.asarray(values, float)
    lo = np.array([r[key]["ci"][0] for r in rows])
    hi = np.array([r[key]["ci"][1] for r in rows])
    return [np.clip(y - lo, 0, None), np.clip(hi - y, 0, None)]


def _sweep_series(rows, var):
    """(label, values, identification accuracies, their interval bars, rows) of each material
    (and inversion, where a sweep ran several) of sweep variable ``var``, in value order."""
    keys = dict.fromkeys((r["material"], r.get("inversion", "lambertian")) for r in rows
                         if r["variable"] == var)
    several = len({inv for _, inv in keys}) > 1
    for m, inv in keys:
        rs = sorted((r for r in rows if r["variable"] == var and r["material"] == m
                     and r.get("inversion", "lambertian") == inv), key=lambda r: r["value"])
        y = np.array([r["identification"]["accuracy"] for r in rs])
        label = f"{_short(m, 22)} ({INVERSION_LABELS.get(inv, inv)})" if several else m
        yield label, [r["value"] for r in rs], y, _ci_err(y, rs), rs


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
    items.append("The legibility classifier held out by " + "; ".join(
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
    for var, e in f["sweeps"].items():
        per = "; ".join(f"{html.escape(_short(m, 22))} {v['min']:.2f}-{v['max']:.2f}"
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


def fig_tilt(results):
    """Identification up to translation against tilt, per material: each inversion and the
    measurement alone (Wilson 95% intervals)."""
    import matplotlib.pyplot as plt

    rows = results["tilt_sweep"]
    mats = list(dict.fromkeys(r["material"] for r in rows))
    cols = [c for c in (*results.get("inversions", ("lambertian",)), "measurement")
            if c in rows[0]]
    fig, axes = plt.subplots(1, len(mats), figsize=(11.5, 3.0), squeeze=False,
                             constrained_layout=True, sharey=True)
    styles = {"lambertian": "o-", "known": "s-", "auto": "^-", "measurement": "k:"}
    for ax, m in zip(axes[0], mats, strict=True):
        rs = sorted((r for r in rows if r["material"] == m), key=lambda r: r["tilt_deg"])
        x = [r["tilt_deg"] for r in rs]
        for c in cols:
            y = np.array([r[c]["identification"]["accuracy"] for r in rs])
            ax.errorbar(x, y, yerr=_ci_err(y, [r[c] for r in rs]), fmt=styles.get(c, "o-"),
                        capsize=2, label=INVERSION_LABELS.get(c, c))
        ax.set(title=_short(m, 24), xlabel="tilt (deg)", ylim=(0, 1.05))
        ax.title.set_fontsize(8)
    axes[0, 0].set_ylabel("identification (up to translation)")
    axes[0, 0].legend(fontsize=6)
    return fig


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
        return [f"<h2>{html.escape(title)}</h2>",
                "<p>Not run in this report: every sample here was simulated with the "
                "seed's confocal transport (Eq. 9: light leaves and re-enters the slab's "
                "face at one point, the BRDF read on its retro slice). <code>clnlos study "
                "--transport both</code> (the <code>--full</code> default) renders the "
                "materials at the legible geometry under Eq. 8 in full too and tabulates "
                "identification, margins and ranks under each.</p>"]
    return [f"<h2>{html.escape(title)}</h2>",
            comparison_html(comparison, comparison["face_rings"], comparison["face_angles"]),
            f"<img alt='{html.escape(title)}' src='data:image/png;base64,"
            f"{_png(fig_transport(comparison))}'/>"]


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
    out = ["<h2>Where the time goes</h2>",
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


def write_report(out_dir, results, plan, res, real=None) -> None:
    import matplotlib

    matplotlib.use("Agg")

    g = results["options"]["grid"]
    figs = [
        ("The seed's Figure 8, side by side (legible geometry)",
         "Per material: the measurement (photon counts) integrated over time with its x-t and "
         "y-t slices, the Lambertian reconstruction's MIP with the true outline (red) and its "
         "x-z and y-z projections (dotted: the true depth), and the MIP of the inversion "
         "with the material's BRDF.",
         fig_figure8(results, plan, res, results['legible_geometry'])),
        ("Identification and IoU against the blob baseline", "", fig_identification(results)),
        ("Every glyph at the legible geometry", "Title: true glyph -> the matched one.",
         fig_materials(results, plan, res, results['legible_geometry'])),
        ("Every glyph at the seed's Table 1 geometry", "Title: true glyph -> the matched one.",
         fig_materials(results, plan, res, results['seed_geometry'])),
        ("Where the material decides legibility: letter size and exposure",
         "Legible geometry; mean over glyphs and noise realisations, Wilson 95% intervals.",
         fig_legibility_sweeps(results)),
        ("Geometry sweeps (the seed's letters)", "", fig_sweeps(results)),
        *([("Tilted glyphs (legible geometry)", "Identification up to a translation; dotted: "
            "the measurement alone.", fig_tilt(results))] if results.get("tilt_sweep")
          else []),
        ("No-reference metrics against ground truth", "", fig_metrics(results, plan, res)),
        ("BRDF of each material (seed Fig. 7)", "", fig_brdf(results)),
    ]
    if results.get("cnn_seed_recipe"):
        figs.insert(-1, ("The seed's CNN recipe (seed Fig. 9)", "", fig_cnn(results)))
    if real is not None and real.get("figure") is not None:
        figs.insert(2, ("A real capture beside its simulation", "", real["figure"]))
    small = results["smallest_legible"]

    def _need(n, var):
        if n[var] is None:
            return "-"
        via = n.get(f"{var}_inversion")
        return f"{n[var]:g}" + (f" ({INVERSION_LABELS.get(via, via)})" if via else "")

    need_rows = [[html.escape(n["material"]),
                  html.escape(INVERSION_LABELS.get(n.get("inversion", "lambertian"),
                                                   n.get("inversion", ""))),
                  _need(n, "letter_height_m"), _need(n, "exposure_s")] for n in small]
    res_rows = [[m, f"{v['lateral_fwhm_m'] * 100:.2f}", f"{v['axial_fwhm_m'] * 100:.2f}"]
                for m, v in results["resolution"].items()
                if isinstance(v, dict) and "lateral_fwhm_m" in v]
    val = results["metric_validation"]
    metric_rows = [[m + (" (labels)" if m == results["labels"]["metric"] else ""),
                    f"{val[m]['identified']:+.2f}", f"{val[m]['iou']:+.2f}",
                    f"{val[m]['iou_excess']:+.2f}", f"{val[m]['depth_error_m']:+.2f}",
                    f"{val[m]['psnr_db']:+.2f}"] for m in METRICS]
    body = [
        "<h1>How the surface material of a hidden target changes what we can read</h1>",
        "<h2>Findings</h2>", findings_html(results),
        f"<p>Mode <b>{results['study']}</b>: {g['points']} x {g['points']} scan points, "
        f"{g['bin_width_s'] * 1e12:.0f} ps bins, 2.54 cm slab (mu_a 0.53 1/m, mu_s' 262 1/m, "
        f"n 1.12), 35 ps pulse, {g['rep_rate_hz'] / 1e6:.0f} MHz, {g['power_w'] * 1e3:.0f} mW "
        f"at {g['wavelength_m'] * 1e9:.0f} nm, 0.1 s per scan point unless swept; "
        f"reconstruction: {g['method']}"
        + f" ({_reconstruction_detail(g)})"
        + f"; glyphs {''.join(results['options']['glyphs'])} (K = "
        f"{len(results['options']['glyphs'])}), {results['options']['seeds']} noise "
        f"realisation(s) each; {results['n_dataset']} reconstructions in all.</p>",
        "<h2>Materials at each geometry</h2>",
        *[_geometry_table(geo) for geo in results["geometries"]],
        "<h2>What the material costs: smallest legible letter and exposure</h2>",
        "<p>Legible geometry; identification >= 0.9 at 0.1 s per point (height) and with "
        "0.3 m letters (exposure); '-': not reached within the swept values.</p>",
        _table(["material", "inversion", "smallest legible letter (m)",
                "exposure needed (s)"], need_rows),
        "<h2>Tilted glyphs: identification up to a translation</h2>", _tilt_html(results),
        "<h2>Measured resolution (seed geometry, noise-free point target)</h2>",
        _table(["method", "lateral FWHM (cm)", "axial FWHM (cm)"], res_rows),
        f"<p>O'Toole's bound with the measured effective temporal FWHM "
        f"{results['resolution']['effective_temporal_fwhm_s'] * 1e12:.0f} ps: "
        f"{results['resolution']['bound_lateral_m'] * 100:.2f} cm.</p>",
        "<h2>A real capture and its simulation</h2>", _real_html(results),
        *classifier_section(results, None if real is None else real.get("thinning"),
                            _table, _png, None if real is None else [
                                r for r in real.get("family", ()) if "mip" in r]),
        *_transport_section(results.get("transport_comparison")),
        "<h2>No-reference metrics against ground truth</h2>",
        "<p>Pearson r over the glyph reconstructions (point-biserial for identified).</p>",
        _table(["metric", "r with identified", "r with IoU", "r with IoU - baseline",
                "r with depth error", "r with PSNR"], metric_rows),
    ]
    for title, caption, fig in figs:
        body.append(f"<h2>{html.escape(title)}</h2>")
        if caption:
            body.append(f"<p>{html.escape(caption)}</p>")
        body.append(f"<img alt='{html.escape(title)}' src='data:image/png;base64,"
                    f"{_png(fig)}'/>")
    body += _cost_html(results)
    doc = (f"<!doctype html><html><head><meta charset='utf-8'>{HTML_GENERATOR}"
           "<meta name='viewport' content='width=device-width, initial-scale=1'>"
           f"<title>clnlos material study</title><style>{STYLE}</style>{OVERFLOW_PROBE}"
           "</head><body>" + "\n".join(body) + "</body></html>")
    with atomic_path(out_dir / "report.html") as tmp:
        tmp.write_text(doc, encoding="utf-8")


def fig_transport(comparison: dict, plan=None, results=None):
    """Identification per material under both transports (Wilson 95% intervals) and the
    NCC margins of one against the other; with samples, one glyph's MIP under each."""
    import matplotlib.pyplot as plt  # optional dependency: only when a report draws

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
              title=f"margins (rank confocal->bistatic); Spearman {fmt_r(c['spearman'])}, "
                    f"Kendall {fmt_r(c['kendall'])}")
    ax[1].legend(fontsize=7)
    return fig


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

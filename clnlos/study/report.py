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

from .quality import METRICS

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


def fig_materials(results, main_res, seeds: int):
    """The first noise realisation's MIP of every material with the true outline."""
    import matplotlib.pyplot as plt

    g = results["options"]["grid"]
    w = g["scan_width_m"]
    mats = results["materials"]
    cols = 5
    rows = int(np.ceil(len(mats) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(11.5, 2.55 * rows), squeeze=False,
                             constrained_layout=True)
    ext = (-w / 2, w / 2, -w / 2, w / 2)
    im = None
    for ax in axes.ravel():
        ax.set_visible(False)
    for j, m in enumerate(mats):
        ax = axes[j // cols, j % cols]
        ax.set_visible(True)
        r = main_res[j * seeds]
        im = ax.imshow(r["mip"], origin="lower", cmap="gray", extent=ext, vmin=0, vmax=1)
        c = np.linspace(-w / 2, w / 2, r["truth"].shape[0] + 1)
        cc = (c[:-1] + c[1:]) / 2
        ax.contour(cc, cc, r["truth"], [0.5], colors="tab:red", linewidths=0.8)
        ax.set_title(f"{_short(m['name'], 24)}\nIoU {m['iou']:.2f} [{m['iou_ci'][0]:.2f}, "
                     f"{m['iou_ci'][1]:.2f}]", fontsize=8)
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.colorbar(im, ax=axes, shrink=0.8, label="MIP / max (albedo, a.u.)")
    return fig


def fig_brdf(results):
    import matplotlib.pyplot as plt

    from ..brdf.models import retro_slice
    from ..brdf.presets import preset_model

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


def fig_iou_by_material(results):
    import matplotlib.pyplot as plt

    mats = results["materials"]
    fig, ax = plt.subplots(1, 2, figsize=(11.5, 3.9), constrained_layout=True)
    x = np.arange(len(mats))
    colours = {1: "tab:green", 2: "tab:orange", 3: "tab:red", None: "tab:gray"}
    iou = np.array([m["iou"] for m in mats])
    lo = iou - np.array([m["iou_ci"][0] for m in mats])
    hi = np.array([m["iou_ci"][1] for m in mats]) - iou
    ax[0].bar(x, iou, yerr=[lo, hi], capsize=3,
              color=[colours[m["seed_label"]] for m in mats])
    ax[0].set_xticks(x)
    ax[0].set_xticklabels([_short(m["name"], 18) for m in mats], rotation=55, ha="right",
                          fontsize=7)
    ax[0].set(ylabel="IoU of the MIP (mean, 95% interval)", ylim=(0, 1),
              title="per material (colour: seed Fig. 9 group 1 green, 2 orange, 3 red)")
    sp = [m["specular_fraction"] for m in mats]
    ax[1].errorbar(sp, iou, yerr=[lo, hi], fmt="o", capsize=3)
    for m, s_, i_ in zip(mats, sp, iou, strict=True):
        ax[1].annotate(_short(m["name"], 14), (s_, i_), fontsize=6, xytext=(3, 3),
                       textcoords="offset points")
    r = results["findings"]["corr_specular_fraction_vs_iou_materials"]
    ax[1].set(xlabel="specular fraction of the reflectance at 45 deg", ylabel="IoU",
              title=f"specular fraction vs IoU (r = {r:+.2f})", ylim=(0, 1))
    return fig


def fig_dataset(results, ds_res, values):
    import matplotlib.pyplot as plt

    iou = np.array([r["iou"] for r in ds_res])
    metric = results["labels"]["metric"]
    fig, ax = plt.subplots(1, 3, figsize=(11.5, 3.6), constrained_layout=True)
    ax[0].hist(iou, bins=20, range=(0, 1), color="tab:blue")
    ax[0].set(xlabel="IoU of the MIP", ylabel="reconstructions",
              title=f"dataset IoU (median {np.median(iou):.2f}, n = {len(iou)})")
    for a, name in ((ax[1], metric), (ax[2], "fft_clarity")):
        sc = a.scatter(values[name], iou, s=6, c=[r["counts"] for r in ds_res], cmap="viridis",
                       norm=__import__("matplotlib").colors.LogNorm())
        a.set(xlabel=name + (" (log10)" if name == "fft_clarity" else " (0..1)"),
              ylabel="IoU", title=f"{name}: r = {results['metrics'][name]:+.2f} with IoU")
    fig.colorbar(sc, ax=ax[1:], label="photon counts in the capture")
    return fig


def fig_cnn(results):
    import matplotlib.pyplot as plt

    cnn = results["cnn"]
    fig, ax = plt.subplots(1, 3, figsize=(11.5, 3.5), constrained_layout=True)
    conf = np.asarray(cnn["confusion"])
    im = ax[0].imshow(conf, cmap="Blues")
    for i in range(3):
        for j in range(3):
            ax[0].text(j, i, str(conf[i, j]), ha="center", va="center")
    ax[0].set(xticks=range(3), yticks=range(3), xticklabels=["1", "2", "3"],
              yticklabels=["1", "2", "3"], xlabel="CNN label", ylabel="true label",
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
    import matplotlib.pyplot as plt

    rows = results["sweeps"]
    variables = list(dict.fromkeys(r["variable"] for r in rows))
    fig, ax = plt.subplots(1, len(variables), figsize=(11.5, 3.6), squeeze=False,
                           constrained_layout=True)
    for a, var in zip(ax[0], variables, strict=True):
        for m in dict.fromkeys(r["material"] for r in rows if r["variable"] == var):
            rs = [r for r in rows if r["variable"] == var and r["material"] == m]
            x = [r["value"] for r in rs]
            y = np.array([r["iou"] for r in rs])
            err = [y - [r["iou_ci"][0] for r in rs], [r["iou_ci"][1] for r in rs] - y]
            a.errorbar(x, y, yerr=err, fmt="o-", capsize=3, label=_short(m, 22))
        a.set(xlabel=SWEEP_AXES.get(var, var), ylabel="IoU of the MIP", ylim=(0, 1))
        a.legend(fontsize=7)
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


def findings_html(results) -> str:
    f = results["findings"]
    mats = results["materials"]
    best = max(mats, key=lambda m: m["iou"])
    worst = min(mats, key=lambda m: m["iou"])
    items = [
        f["statement"],
        f"IoU ranges from {worst['iou']:.2f} ({html.escape(worst['name'])}) to "
        f"{best['iou']:.2f} ({html.escape(best['name'])}), a spread of "
        f"{f['iou_spread_materials']:.2f}.",
        f"Labels from <b>{results['labels']['metric']}</b> (no reference needed) correlate "
        f"with IoU at r = {results['labels']['corr_with_iou']:+.2f} over the "
        f"{results['n_dataset']} dataset reconstructions; the seed's FFT clarity at "
        f"r = {results['metrics']['fft_clarity']:+.2f}.",
        f"The CNN reproduces the labels of held-out reconstructions with accuracy "
        f"{results['cnn']['val_accuracy']:.2f} (majority class "
        f"{results['cnn']['majority_baseline']:.2f}).",
        f"Our labels agree with the seed's Figure 9 for "
        f"{results['seed_figure9_agreement']} of {len(mats)} materials (the CNN's for "
        f"{results['seed_figure9_agreement_cnn']}).",
    ]
    lm = f.get("largest_material_spread")
    if lm:
        items.append(f"The material matters most {sweep_condition(lm['variable'], lm['value'])}"
                     f": IoU differs "
                     f"by {lm['iou_spread']:.2f} between the swept materials (at the seed "
                     f"geometry: {f['iou_spread_materials']:.2f} over all ten).")
    for var, e in f["sweeps"].items():
        per = "; ".join(f"{html.escape(_short(m, 22))} {v['min']:.2f}-{v['max']:.2f}"
                        for m, v in e["per_material"].items())
        items.append(f"{SWEEP_AXES.get(var, var)}: IoU spans {per}. Mean change with the "
                     f"variable {e['geometry_effect']:.2f} against mean spread between "
                     f"materials {e['material_effect']:.2f}: <b>{e['dominant']}</b> "
                     "dominates.")
    return "<ul class='findings'>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>"


def write_report(out_dir, results, main_res, ds_res, labels, values) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from ..io import atomic_path
    from ..outputs import HTML_GENERATOR

    g = results["options"]["grid"]
    seeds = results["options"]["seeds"]
    mats = results["materials"]
    figs = [
        ("Reconstructions of 'UT' behind the slab (seed Fig. 8)",
         "Max-intensity projection of each material's first noise realisation; red: the "
         "true letters. Titles: IoU over all realisations with its 95% interval.",
         fig_materials(results, main_res, seeds)),
        ("IoU per material", "", fig_iou_by_material(results)),
        ("BRDF of each material (seed Fig. 7)", "", fig_brdf(results)),
        ("Dataset and label metrics", "", fig_dataset(results, ds_res, values)),
        ("CNN classifier (seed Fig. 9)", "", fig_cnn(results)),
        ("Sweeps: where the material matters, where the geometry dominates",
         "'UT' at the seed geometry unless varied; mean over noise realisations.",
         fig_sweeps(results)),
    ]
    mat_rows = [[html.escape(m["name"]), html.escape(m["brdf_class"]),
                 f"{m['specular_fraction']:.2f}", f"{m['iou']:.3f}",
                 f"[{m['iou_ci'][0]:.2f}, {m['iou_ci'][1]:.2f}]",
                 f"{m['depth_error_m'] * 100:.1f}", f"{m['psnr_db']:.1f}",
                 f"{m['photon_counts']:.2g}", m["label"], m["cnn_label"],
                 m["seed_label"] if m["seed_label"] is not None else "-",
                 m["clarity_label"]] for m in mats]
    val = results["metric_validation"]
    metric_rows = [[m + (" (labels)" if m == results["labels"]["metric"] else ""),
                    f"{val[m]['iou']:+.2f}", f"{val[m]['depth_error_m']:+.2f}",
                    f"{val[m]['psnr_db']:+.2f}"] for m in METRICS]
    body = [
        "<h1>How the surface material of a hidden target changes what we reconstruct</h1>",
        "<h2>Findings</h2>", findings_html(results),
        f"<p>Mode <b>{results['study']}</b>: scan {g['scan_width_m']} m x "
        f"{g['scan_width_m']} m of {g['points']} x {g['points']} points, "
        f"{g['bin_width_s'] * 1e12:.0f} ps bins, 2.54 cm slab (mu_a 0.53 1/m, mu_s' 262 1/m, "
        f"n 1.12), 35 ps pulse, {g['rep_rate_hz'] / 1e6:.0f} MHz, {g['power_w'] * 1e3:.0f} mW "
        f"at {g['wavelength_m'] * 1e9:.0f} nm, 0.1 s per scan point for the materials; "
        f"reconstruction: {g['method']}"
        + (f" ({g['iterations']} iterations)" if g["method"] == "iterative" else "")
        + f"; {seeds} noise realisations per material; {results['n_dataset']} dataset "
        "reconstructions.</p>",
        "<h2>Materials</h2>",
        _table(["material", "BRDF class", "specular fraction", "IoU", "95% interval",
                "depth error (cm)", "PSNR (dB)", "photons", "label", "CNN label",
                "seed Fig. 9", "FFT label"], mat_rows),
        "<h2>No-reference metrics against ground truth</h2>",
        "<p>Pearson r over the dataset. Labels: " + html.escape(results["labels"]["metric"])
        + f", cut at the seed's split 19.3/51.4/29.3 % (counts {results['labels']['counts']}"
        ").</p>",
        _table(["metric", "r with IoU", "r with depth error", "r with PSNR"], metric_rows),
    ]
    for title, caption, fig in figs:
        body.append(f"<h2>{html.escape(title)}</h2>")
        if caption:
            body.append(f"<p>{html.escape(caption)}</p>")
        body.append(f"<img alt='{html.escape(title)}' src='data:image/png;base64,"
                    f"{_png(fig)}'/>")
    t = results["timings_s"]
    body.append("<p>Timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()) + "</p>")
    doc = (f"<!doctype html><html><head><meta charset='utf-8'>{HTML_GENERATOR}"
           "<meta name='viewport' content='width=device-width, initial-scale=1'>"
           f"<title>clnlos material study</title><style>{STYLE}</style>{OVERFLOW_PROBE}"
           "</head><body>" + "\n".join(body) + "</body></html>")
    with atomic_path(out_dir / "report.html") as tmp:
        tmp.write_text(doc, encoding="utf-8")

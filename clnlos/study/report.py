"""The study report: self-contained HTML (PNG figures embedded) beside results.json."""

from __future__ import annotations

import base64
import html
import io

import numpy as np


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _fig_brdf(results):
    import matplotlib.pyplot as plt

    from ..brdf.models import retro_slice
    from ..brdf.presets import preset_model, preset_table

    table = preset_table()
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    ts = np.radians(np.linspace(-89, 89, 357))
    for m in results["materials"]:
        if m["name"] not in table:
            continue
        model = preset_model(m["name"])
        r = retro_slice(model, 91)
        ax[0].semilogy(np.linspace(0, 90, 91), np.maximum(r, 1e-4), label=m["name"])
        f = model(np.full_like(ts, np.pi / 4), 0 * ts, np.abs(ts), np.where(ts >= 0, np.pi, 0))
        ax[1].semilogy(np.degrees(ts), np.maximum(f, 1e-4))
    ax[0].set(xlabel="theta (deg)", ylabel="f(w, w) (1/sr)",
              title="confocal retro-reflection slice")
    ax[1].set(xlabel="theta_s (deg, + = forward)", title="in plane, theta_i = 45 deg")
    ax[0].legend(fontsize=7)
    return fig


def _fig_recon(results, main_res):
    import matplotlib.pyplot as plt

    n = len(main_res)
    fig, ax = plt.subplots(3, n, figsize=(2.1 * n, 6.5), squeeze=False)
    for j, (m, r) in enumerate(zip(results["materials"], main_res, strict=True)):
        ax[0, j].imshow(r["mip"], origin="lower", cmap="gray")
        ax[0, j].set_title(f"{m['name'][:18]}\nIoU {m['iou']:.2f}", fontsize=7)
        ax[1, j].imshow(r["xt"], origin="lower", aspect="auto", cmap="magma")
        ax[2, j].imshow(r["yt"], origin="lower", aspect="auto", cmap="magma")
        for a in ax[:, j]:
            a.set_xticks([])
            a.set_yticks([])
    ax[0, 0].set_ylabel("MIP (x-y)")
    ax[1, 0].set_ylabel("x-t slice")
    ax[2, 0].set_ylabel("y-t slice")
    return fig


def _fig_classes(results, ds_res, labels):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    conf = np.asarray(results["cnn"]["confusion"])
    ax[0].imshow(conf, cmap="Blues")
    for i in range(3):
        for j in range(3):
            ax[0].text(j, i, str(conf[i, j]), ha="center", va="center")
    ax[0].set(xticks=range(3), yticks=range(3), xticklabels=["1", "2", "3"],
              yticklabels=["1", "2", "3"], xlabel="CNN label", ylabel="clarity label",
              title=f"validation, accuracy {results['cnn_validation_accuracy']:.2f}")
    names = [m["name"][:14] for m in results["materials"]]
    x = np.arange(len(names))
    ax[1].bar(x - 0.2, [m["clarity_label"] for m in results["materials"]], 0.4, label="FFT")
    ax[1].bar(x + 0.2, [m["cnn_label"] for m in results["materials"]], 0.4, label="CNN")
    ax[1].set(xticks=x, yticks=[1, 2, 3], title="labels (1 clear, 2 medium, 3 fuzzy)")
    ax[1].set_xticklabels(names, rotation=70, fontsize=7)
    ax[1].legend()
    s = np.array([r["clarity"] for r in ds_res])
    ax[2].scatter(s, [r["iou"] for r in ds_res], c=labels, s=8, cmap="viridis")
    ax[2].set(xscale="log", xlabel="FFT clarity score", ylabel="IoU of the MIP",
              title="dataset: clarity vs ground truth")
    return fig


def _fig_specular(results):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    sp = [m["specular_fraction"] for m in results["materials"]]
    for a, key, lab in ((ax[0], "iou", "IoU"), (ax[1], "clarity_score", "clarity score")):
        a.scatter(sp, [m[key] for m in results["materials"]])
        for m in results["materials"]:
            a.annotate(m["name"][:12], (m["specular_fraction"], m[key]), fontsize=6)
        a.set(xlabel="specular fraction of the BRDF (45 deg)", ylabel=lab)
    return fig


def write_report(out_dir, results, main_res, ds_res, labels) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from ..io import atomic_path

    figs = [("BRDF of each material (seed Fig. 7)", _fig_brdf(results)),
            ("Reconstructions of 'UT' behind the slab (seed Fig. 8)", _fig_recon(results,
                                                                               main_res)),
            ("Clarity classification (seed Fig. 9)", _fig_classes(results, ds_res, labels)),
            ("Specular fraction against reconstruction quality", _fig_specular(results))]
    g = results["options"]["grid"]
    rows = "".join(
        f"<tr><td>{html.escape(m['name'])}</td><td>{html.escape(m['brdf_class'])}</td>"
        f"<td>{m['specular_fraction']:.2f}</td><td>{m['clarity_score']:.3g}</td>"
        f"<td>{m['clarity_label']}</td><td>{m['cnn_label']}</td><td>{m['iou']:.3f}</td>"
        f"<td>{m['depth_error_m'] * 100:.1f}</td><td>{m['psnr_db']:.1f}</td></tr>"
        for m in results["materials"])
    f = results["findings"]
    body = [
        "<h1>clnlos material study</h1>",
        f"<p><b>{html.escape(f['statement'])}</b></p>",
        f"<p>Mode: <b>{results['study']}</b>; {results['n_dataset']} dataset reconstructions; "
        f"scan {g['scan_width_m']} m x {g['scan_width_m']} m, {g['points']}x{g['points']} "
        f"points, {g['bins']} bins of {g['bin_width_s'] * 1e12:.0f} ps, reconstructed on "
        f"{g['recon_bins']} bins; slab 2.54 cm, mu_a 0.53 1/m, mu_s' 262 1/m, n 1.12; "
        f"35 ps pulse, 10 MHz, 400 mW at 532 nm.</p>",
        f"<p>Clarity labels from thresholds {results['clarity_thresholds'][0]:.3g} (clear) "
        f"and {results['clarity_thresholds'][1]:.3g} (fuzzy), the dataset quantiles that give "
        f"the seed's 19.3/51.4/29.3% split: counts {results['label_counts']}. "
        f"CNN validation accuracy {results['cnn_validation_accuracy']:.3f}.</p>",
        "<p>Correlations over the dataset: clarity vs IoU "
        f"{f['corr_clarity_vs_iou_dataset']:+.2f}, vs depth error "
        f"{f['corr_clarity_vs_depth_error_dataset']:+.2f}, vs PSNR "
        f"{f['corr_clarity_vs_psnr_dataset']:+.2f}. Over the materials: specular fraction "
        f"vs IoU {f['corr_specular_fraction_vs_iou_materials']:+.2f}, vs clarity "
        f"{f['corr_specular_fraction_vs_clarity_materials']:+.2f}.</p>",
        "<table border=1 cellpadding=3><tr><th>material</th><th>BRDF class</th>"
        "<th>specular fraction</th><th>clarity</th><th>FFT label</th><th>CNN label</th>"
        "<th>IoU</th><th>depth error (cm)</th><th>PSNR (dB)</th></tr>" + rows + "</table>",
    ]
    for title, fig in figs:
        body.append(f"<h2>{html.escape(title)}</h2><img src='data:image/png;base64,"
                    f"{_png(fig)}'/>")
    t = results["timings_s"]
    body.append("<p>Timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()) + "</p>")
    doc = ("<!doctype html><html><head><meta charset='utf-8'><title>clnlos study</title>"
           "</head><body style='font-family:sans-serif;max-width:1500px'>" + "\n".join(body)
           + "</body></html>")
    with atomic_path(out_dir / "report.html") as tmp:
        tmp.write_text(doc, encoding="utf-8")

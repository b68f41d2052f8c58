"""The study report's figures (matplotlib, imported where a figure is drawn): the seed's
Figure 8 side by side, every glyph per material, identification and IoU, the sweeps, the tilt
sweep, the metrics, the BRDFs, the CNN, the transport comparison. Each returns a figure;
:mod:`clnlos.study.report.page` embeds them."""

from __future__ import annotations

import numpy as np

from clnlos.brdf.models import retro_slice
from clnlos.brdf.presets import preset_model
from clnlos.physics.constants import C0
from clnlos.study.findings.transport import TRANSPORTS, fmt_r


def short_name(name: str, n: int = 16) -> str:
    return name if len(name) <= n else name[:n - 1] + "."


def outline_mask(ax, truth, w):
    c = np.linspace(-w / 2, w / 2, truth.shape[0] + 1)
    cc = (c[:-1] + c[1:]) / 2
    ax.contour(cc, cc, truth, [0.5], colors="tab:red", linewidths=0.8)


def first_sample(plan, res, geometry: str, material: str, glyph: str | None = None,
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
    glyphs = geo["glyphs"]
    mats = geo["materials"]
    w = geo["scan_width_m"]
    # a fixed grid, no layout engine: solving one for 80 panels costs seconds per figure
    fig, axes = plt.subplots(len(mats), len(glyphs), figsize=(11.5, 1.45 * len(mats) + 0.6),
                             squeeze=False, gridspec_kw={"left": 0.1, "right": 0.93,
                                                         "top": 0.97, "bottom": 0.04,
                                                         "wspace": 0.05, "hspace": 0.3})
    ext = (-w / 2, w / 2, -w / 2, w / 2)
    im = None
    for i, m in enumerate(mats):
        for j, g in enumerate(glyphs):
            ax = axes[i, j]
            _, r = first_sample(plan, res, geometry, m["name"], g)
            im = ax.imshow(r["mip"], origin="lower", cmap="gray", extent=ext, vmin=0, vmax=1)
            outline_mask(ax, r["truth"], w)
            ok = "ok" if r["identified"] else "no"
            ax.set_title(f"{g} -> {r['identified_as']} ({ok})", fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(short_name(m["name"], 18), fontsize=7)
    axes[-1, 0].set_xticks([-w / 2, 0, w / 2])
    axes[-1, 0].set_xlabel("x (m)", fontsize=7)
    fig.colorbar(im, cax=fig.add_axes((0.945, 0.35, 0.01, 0.3)), label="MIP / max (a.u.)")
    return fig


def fig_figure8(results, plan, res, geometry: str):
    """The seed's Figure 8 side by side, per material (glyph E, first realisation): the
    measurement integrated over time with its x-t and y-t slices through the scan centre,
    and the reconstruction's MIP (true outline in red) with its x-z and y-z projections."""
    import matplotlib.pyplot as plt

    geo = next(g for g in results["geometries"] if g["name"] == geometry)
    mats = geo["materials"]
    w = geo["scan_width_m"]
    glyph = geo["glyphs"][0]
    aware = next((inv for inv in ("known", "auto") if inv in results.get("inversions", ())),
                 None)
    ncol = 7 if aware else 6
    # a fixed grid, no layout engine (see fig_materials)
    fig, axes = plt.subplots(len(mats), ncol, figsize=(11.5, 1.75 * len(mats) + 0.8),
                             squeeze=False, gridspec_kw={"left": 0.09, "right": 0.925,
                                                         "top": 0.95, "bottom": 0.04,
                                                         "wspace": 0.45, "hspace": 0.12})
    titles = ("measurement, sum over t", "x-t (y = 0)", "y-t (x = 0)",
              "Lambertian MIP", "x-z (max over y)", "y-z (max over x)",
              f"{INVERSION_LABELS.get(aware, '')} MIP")
    for i, m in enumerate(mats):
        _, r = first_sample(plan, res, geometry, m["name"], glyph)
        _, ra = (None, None) if aware is None else first_sample(plan, res, geometry,
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
                outline_mask(ax, r["truth"], w)
            if j in (4, 5):
                ax.axhline(geo["depth_m"], color="tab:red", lw=0.6, ls=":")
            # each column's x axis is the same in every row: its numbers on the bottom row
            ax.tick_params(labelsize=6, labelbottom=i == len(mats) - 1)
            if i == 0:
                ax.set_title(titles[j], fontsize=8)
            if i == len(mats) - 1:
                ax.set_xlabel("x (m)" if j in (0, 1, 3, 4, 6) else "y (m)", fontsize=7)
            ax.set_ylabel({0: f"{short_name(m['name'], 16)}\ny (m)", 1: "t (ns)", 2: "t (ns)",
                           3: "y (m)", 4: "z (m)", 5: "z (m)", 6: "y (m)"}[j], fontsize=7)
        if i == 0:  # beside the grid, in axes of their own
            fig.colorbar(first, cax=fig.add_axes((0.955, 0.55, 0.01, 0.3)),
                         label="measurement: counts / max")
            fig.colorbar(im, cax=fig.add_axes((0.955, 0.15, 0.01, 0.3)),
                         label="reconstruction: / max (a.u.)")
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
                  yerr=ci_error_bars(acc, g["materials"]),
                  capsize=2, label=f"{g['name']} (stroke/res {g['stroke_over_resolution']:.1f})")
        box = [m["iou_box_baseline"] for m in g["materials"]]
        ax[1].scatter(box, [m["iou"] for m in g["materials"]], label=g["name"], s=18)
    chance = geos[0]["materials"][0]["identification"]["chance"]
    ax[0].axhline(chance, color="gray", ls=":", label=f"chance 1/K = {chance:.3f}")
    ax[0].set_xticks(x)
    ax[0].set_xticklabels([short_name(n, 18) for n in names], rotation=55, ha="right",
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
        for m, x, y, err, rs in sweep_series(rows, var):
            fmt = "o-" if rs[0].get("inversion", "lambertian") == "lambertian" else "s--"
            a.errorbar(x, y, yerr=err, fmt=fmt, capsize=3, label=short_name(m, 36))
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
                       label=short_name(m["name"], 22))
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


def fig_sweeps(results):
    """The geometry sweeps at the seed's letter size: identification (top) and IoU over its
    box baseline (bottom) against each variable."""
    import matplotlib.pyplot as plt

    rows = results["sweeps"]
    variables = list(dict.fromkeys(r["variable"] for r in rows))
    fig, ax = plt.subplots(2, len(variables), figsize=(11.5, 6.4), squeeze=False,
                           constrained_layout=True)
    for j, var in enumerate(variables):
        for m, x, y, err, rs in sweep_series(rows, var):
            ax[0, j].errorbar(x, y, yerr=err, fmt="o-", capsize=3, label=short_name(m, 22))
            ax[1, j].plot(x, [r["iou_excess"] for r in rs], "o-", label=short_name(m, 22))
        ax[0, j].axhline(rows[0]["identification"]["chance"], color="gray", ls=":", lw=0.8)
        ax[0, j].set(xlabel=SWEEP_AXES.get(var, var), ylabel="identification accuracy",
                     ylim=(0, 1.05))
        ax[1, j].axhline(0, color="gray", ls=":", lw=0.8)
        ax[1, j].set(xlabel=SWEEP_AXES.get(var, var), ylabel="IoU - box baseline IoU")
        ax[0, j].legend(fontsize=7)
    return fig


def ci_error_bars(values, rows, key="identification"):
    """errorbar's [below, above] of each row's 95% interval around ``values`` (never < 0)."""
    y = np.asarray(values, float)
    lo = np.array([r[key]["ci"][0] for r in rows])
    hi = np.array([r[key]["ci"][1] for r in rows])
    return [np.clip(y - lo, 0, None), np.clip(hi - y, 0, None)]


def sweep_series(rows, var):
    """(label, values, identification accuracies, their interval bars, rows) of each material
    (and inversion, where a sweep ran several) of sweep variable ``var``, in value order."""
    keys = dict.fromkeys((r["material"], r.get("inversion", "lambertian")) for r in rows
                         if r["variable"] == var)
    several = len({inv for _, inv in keys}) > 1
    for m, inv in keys:
        rs = sorted((r for r in rows if r["variable"] == var and r["material"] == m
                     and r.get("inversion", "lambertian") == inv), key=lambda r: r["value"])
        y = np.array([r["identification"]["accuracy"] for r in rs])
        label = f"{short_name(m, 22)} ({INVERSION_LABELS.get(inv, inv)})" if several else m
        yield label, [r["value"] for r in rs], y, ci_error_bars(y, rs), rs


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
            ax.errorbar(x, y, yerr=ci_error_bars(y, [r[c] for r in rs]), fmt=styles.get(c, "o-"),
                        capsize=2, label=INVERSION_LABELS.get(c, c))
        ax.set(title=short_name(m, 24), xlabel="tilt (deg)", ylim=(0, 1.05))
        ax.title.set_fontsize(8)
    axes[0, 0].set_ylabel("identification (up to translation)")
    axes[0, 0].legend(fontsize=6)
    return fig


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

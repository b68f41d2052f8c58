"""The shared real CDT captures reconstructed with defaults (no SNR in the config: the
auto rule of clnlos.inverse.gcv) against the published settings: the correlation of the two
max-intensity projections per capture and method, with today's photon rule beside them
(and, for the iterative method, its Wiener-first model at the published settings).
Writes tools/results/real_cdt_defaults.{csv,json} and real_cdt_defaults.png (the MIPs).

    .venv/bin/python tools/real_cdt_defaults.py [--shared ../shared/data] [--device P:D]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"
# (capture, its published settings): resolution_70 shares letters_ut's (shared README)
CAPTURES = (("letters_ut.mat", "cdt_letters_ut.toml"), ("letter_s.mat", "cdt_letter_s.toml"),
            ("resolution_70.mat", "cdt_letters_ut.toml"))
METHODS = ("iterative", "lct", "fk")


def mip_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two max-intensity projections of [z, y, x] volumes."""
    x, y = a.max(axis=0).ravel(), b.max(axis=0).ravel()
    return float(np.corrcoef(x, y)[0, 1])


def main(argv=None) -> int:
    from matplotlib.figure import Figure

    from clnlos.bench.oracle import write_rows
    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.pipeline import reconstruct
    from clnlos.inverse.preprocessing import resolve_geometry
    from clnlos.inverse.snr import combined_snr, lightcone_snr
    from clnlos.io.files import atomic_path, read_capture, save_figure_file

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--device", default=None)
    a = ap.parse_args(argv)
    rows, mips = [], []
    for cap_name, cfg_name in CAPTURES:
        cap = read_capture(Path(a.shared) / "cdt" / cap_name)
        published = ReconstructionConfig.from_toml(ROOT / "examples" / cfg_name)
        for m in METHODS:
            pub = reconstruct(cap, published.replace(method=m).validate(), device=a.device)
            dflt_cfg = published.replace(method=m, snr="auto", inversion_snr="auto")
            dflt = reconstruct(cap, dflt_cfg.validate(), device=a.device)
            old = combined_snr(dflt.noise["snr"], dflt.params["model_snr_used"])
            today = reconstruct(cap, dflt_cfg.replace(snr=old, inversion_snr=lightcone_snr(
                old)).validate(), device=a.device)
            # the iterative method's former model (Wiener first) at the published settings
            first = (mip_correlation(reconstruct(cap, published.replace(
                method=m, slab_model="none").validate(), device=a.device).volume, pub.volume)
                if m == "iterative" else None)
            rows.append({"capture": cap_name, "method": m,
                         "corr_default": mip_correlation(dflt.volume, pub.volume),
                         "corr_today": mip_correlation(today.volume, pub.volume),
                         "default_snr": dflt.params["snr_used"],
                         "default_inversion_snr": dflt.params.get("inversion_snr_used"),
                         "today_snr": old, "published_snr": published.snr,
                         "published_inversion_snr": published.inversion_snr,
                         "corr_wiener_first": first})
            mips.append((f"{cap_name} {m}", pub.volume.max(axis=0), dflt.volume.max(axis=0),
                         resolve_geometry(cap, published)[2]))
            r = rows[-1]
            print(f"{cap_name} {m}: corr(default, published) {r['corr_default']:.3f}, "
                  f"today {r['corr_today']:.3f}; SNRs {r['default_snr']:.3g} / "
                  f"{r['default_inversion_snr'] or 0:.3g}", flush=True)
    print("wrote", *write_rows(rows, RESULTS / "real_cdt_defaults"))
    fig = Figure(figsize=(6 * 2.3, 2.3 * len(CAPTURES) + 0.4), layout="constrained")
    axes = fig.subplots(len(CAPTURES), 2 * len(METHODS), squeeze=False)
    for k, (title, pub, dflt, width) in enumerate(mips):
        row = axes[k // len(METHODS)]
        ext = (-width / 2, width / 2, -width / 2, width / 2)  # the scan grid, wall coordinates
        for j, (img, what) in enumerate(((pub, "published"), (dflt, "default"))):
            ax = row[2 * (k % len(METHODS)) + j]
            im = ax.imshow(img / max(img.max(), 1e-30), origin="lower", cmap="gray",
                           extent=ext, vmin=0, vmax=1)
            ax.set_title(f"{title}\n{what} SNRs", fontsize=7)
            ax.tick_params(labelsize=6)
            ax.set_xlabel("x (m)", fontsize=7)
            if ax is row[0]:
                ax.set_ylabel("y (m)", fontsize=7)
        if k % len(METHODS) == len(METHODS) - 1:
            cb = fig.colorbar(im, ax=list(row), shrink=0.9, pad=0.01)
            cb.set_label("max-intensity projection / its max", fontsize=7)
            cb.ax.tick_params(labelsize=6)
    out = RESULTS / "real_cdt_defaults.png"
    with atomic_path(out) as tmp:
        save_figure_file(fig, tmp)
    print("wrote", out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The light-cone transform release read as released: every capture in ``SHARED/lct`` with
``clnlos reconstruct``'s defaults (and any further methods asked for) against an
independent float64 port of the published pipeline (tests/reference/lct_published.py) in the
published display orientation and depth crop: the NCC of the front views, of their fine
detail (the image less a 3-pixel Gaussian blur of itself) and the depth of the brightest
voxel. Writes tools/results/lct_release_check.{csv,json,png} (the front views, top row the
published pipeline's), or STEM.{csv,json,png} with --out STEM.

    .venv/bin/python tools/lct_release_check.py [--shared ../shared/data] [--methods lct iterative]
        [--out tools/results/lct_release_check]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"
sys.path.insert(0, str(ROOT / "tests"))


def detail(img: np.ndarray) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    return img - gaussian_filter(img, 3)


def main(argv=None) -> int:
    import scipy.io
    from matplotlib.figure import Figure
    from scipy.ndimage import zoom

    import clnlos
    from clnlos.bench.oracle import write_rows
    from clnlos.io.files import save_figure_file
    from clnlos.study.real.materials import ncc
    from reference.lct_published import PUBLISHED_Z_OFFSET, published_lct

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared" / "data"))
    ap.add_argument("--methods", nargs="+", default=["lct"])
    ap.add_argument("--out", default=str(RESULTS / "lct_release_check"),
                    help="path stem of the .csv, .json and .png written")
    ap.add_argument("--brdf", nargs="+", default=["default"],
                    help="reflectance assumed by each method run: default (none given) or "
                         "a --brdf value (e.g. auto)")
    args = ap.parse_args(argv)
    files = sorted(Path(args.shared, "lct").glob("*.mat"))
    if not files:
        print(f"no captures in {args.shared}/lct")
        return 2
    rows, views = [], []
    for f in files:
        d = scipy.io.loadmat(f)
        ref, dz, z0 = published_lct(d["rect_data"], float(d["width"].ravel()[0]),
                                    diffuse="diffuse" in f.stem,
                                    z_offset=PUBLISHED_Z_OFFSET.get(f.stem))
        front_ref = ref.max(axis=0)
        z_ref = z0 + np.unravel_index(np.argmax(ref), ref.shape)[0] * dz
        col = [("published", front_ref)]
        for method in args.methods:
            for brdf in args.brdf:
                kw = {} if brdf == "default" else {"brdf": brdf}
                t0 = time.perf_counter()
                rec = clnlos.reconstruct(f, method=method, **kw)
                wall = time.perf_counter() - t0
                front = rec.volume.max(axis=0)[::-1, :]  # row 0 at the top, as imagesc
                if front.shape != front_ref.shape:
                    front = zoom(front, front_ref.shape[0] / front.shape[0], order=1)
                kz = np.unravel_index(np.argmax(rec.volume), rec.volume.shape)[0]
                z = (kz + 0.5) * rec.bin_width_s * clnlos.C0 / 2
                row = {"capture": f.stem, "method": method, "brdf": brdf,
                       "ncc_front": ncc(front, front_ref),
                       "ncc_detail": ncc(detail(front), detail(front_ref)),
                       "depth_m": z, "published_depth_m": z_ref, "depth_error_m": z - z_ref,
                       "brdf_used": rec.params.get("brdf_used"),
                       "brdf_chosen": rec.params.get("brdf_chosen"),
                       # the lobe search's held-out scores (whole volume; surface) and cost
                       "brdf_tried": rec.params.get("brdf_tried"),
                       "brdf_tried_surface": rec.params.get("brdf_tried_surface"),
                       "brdf_choice_s": rec.params.get("brdf_choice_s"),
                       "falloff_used": rec.params.get("falloff_used"),
                       "iterations_stop": rec.params.get("iterations_stop"),
                       "iterations_run": (rec.solver or {}).get("iterations"),
                       "depth_end_m": rec.params.get("depth_end_m"),  # LCT: the last light
                       "wall_s": wall, "stage_s": float(sum(rec.timings_s.values()))}
                rows.append(row)
                print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                               for k, v in row.items()), flush=True)
                col.append((f"{method} {brdf}", front))
        views.append((f.stem, col))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_rows(rows, out)
    n = len(views[0][1])
    fig = Figure(figsize=(2.2 * len(views), 2.3 * n), layout="constrained")
    ax = np.asarray(fig.subplots(n, len(views))).reshape(n, len(views))
    for j, (name, col) in enumerate(views):
        for i, (label, img) in enumerate(col):
            ax[i, j].imshow(img, cmap="gray")
            ax[i, j].set_title(f"{name.replace('data_', '')}\n{label}", fontsize=7)
            ax[i, j].set_axis_off()
    save_figure_file(fig, out.with_suffix(".png"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

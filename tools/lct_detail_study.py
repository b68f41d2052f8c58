"""What separates clnlos's LCT front view of the release's diffuse S from the published
pipeline's in fine detail (the image less a 3-pixel Gaussian blur of itself, as
tools/lct_release_check.py scores it). Three measurements, one row each:

* ``split_half``: the published pipeline (tests/reference/lct_published.py) on two binomial
  halves of every capture's photon counts (seed 0): the NCC of the two halves' fine detail
  and of each half's against the whole capture's -- how much of the published view's fine
  detail is the scene and how much the draw of its photons.
* ``morph``: the diffuse S through a float64 NumPy copy of clnlos's LCT stages (background
  floor subtracted, mass-conserving t -> v resampling, (t/T)^p at bin centres, the light cone
  centred on the scan point and split linearly between v bins), checked against
  ``clnlos.reconstruct``'s volume, with one published step swapped in at a time, and the
  published pipeline with one clnlos step swapped in at a time. Every cone is normalised to
  unit sum, so every SNR is in clnlos's units (the published 0.08 is 0.08 (2N)^2 there).
  Scores over the whole depth (``full``) and in the published display's depth crop; the
  copy leaves out clnlos's cut at the last light (clnlos.inverse.lct.LCTMethod) but where it
  is checked against clnlos's volume.
* ``registration``: a point scatterer in front of a scan point (16 x 16 scan, 128 bins),
  noise-free: the centroid of the front view around it, in pixels (display rows down,
  columns right), for clnlos's LCT and for the published pipeline.

    .venv/bin/python tools/lct_detail_study.py [--shared ../shared/data]

Writes tools/results/lct_detail_study.{csv,json} (docs/validation/lct-release.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "tools" / "results"
sys.path.insert(0, str(ROOT / "tests"))

DIRECT_BINS = 600  # native 4 ps bins the published code zeroes
SUM_BINS = 4       # ... and sums into one 16 ps bin
C_PUBLISHED = 3e8


def detail(img: np.ndarray) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    return img - gaussian_filter(img, 3)


def scores(front: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(NCC of the front views, NCC of their fine detail)."""
    from clnlos.study.real.materials import ncc

    return ncc(front, ref), ncc(detail(front), detail(ref))


def cone(kind: str, m: int, n: int, width: float, bin_width_s: float) -> np.ndarray:
    """Unit-sum light cone on the padded (2m, 2n, 2n) grid, wrap order, lateral axes (j, i)
    of the published orientation: "clnlos" (centred on the scan point, clnlos's pitch 2w/n,
    split linearly between v bins), "half_pitch" (centred half a pitch toward -j, -i, as the
    published linspace(-1, 1, 2n) grid puts it), "half_pitch_published_pitch" (that grid's
    step 2/(2n-1) and z step 2/(2m-1) too), "published" (the published shell itself: those
    and the nearest v bin)."""
    from clnlos.physics.grid import grid_offsets
    from clnlos.physics.lightcone import lightcone_psf_grid
    from reference.lct_published import _shell_psf

    slope = width / (m * C_PUBLISHED * bin_width_s)
    if kind == "published":
        h = _shell_psf(n, m, slope)
        return h / h.sum()
    off = 0.0 if kind == "clnlos" else -0.5
    scale = 1.0
    if kind == "half_pitch_published_pitch":
        scale = (2 * m - 1) / (2 * m) * (2 * n) ** 2 / (2 * n - 1) ** 2
    o = grid_offsets(2 * n, 1.0) - off
    shift = (o[:, None] ** 2 + o[None, :] ** 2) * 16 * m * slope**2 / n**2 * scale
    h = lightcone_psf_grid(shift, 2 * m, 2 * m - 1)
    return h / h.sum()


def stages(rect: np.ndarray, width: float, *, falloff: float, snr: float, floor: bool,
           weight: str, resampling: str, cone_kind: str) -> np.ndarray:
    """vol[z, row, col] (published display orientation, clamped at 0) of ``rect_data``
    through the LCT with each step clnlos's ("clnlos") or the published one ("published")."""
    from clnlos.inverse.lct import t_to_v_matrix, u_to_z_matrix
    from clnlos.inverse.snr import estimate_noise
    from reference.lct_published import _resampling

    d = np.transpose(np.asarray(rect, np.float64), (2, 1, 0)).copy()  # (t, j, i)
    d[:DIRECT_BINS] = 0
    if floor:
        d[DIRECT_BINS:] -= estimate_noise(d, 4e-12).background_per_bin
    m = d.shape[0] // SUM_BINS
    d = d.reshape(m, SUM_BINS, *d.shape[1:]).sum(axis=1)
    n = d.shape[1]
    grid = np.linspace(0, 1, m) if weight == "published" else (np.arange(m) + 0.5) / m
    if resampling == "published":
        to_v = _resampling(m)
        to_z = to_v.T
    else:
        to_v, to_z = t_to_v_matrix(m, 0).toarray(), u_to_z_matrix(m).toarray()
    padded = np.zeros((2 * m, 2 * n, 2 * n))
    padded[:m, :n, :n] = (to_v @ (grid[:, None, None] ** falloff * d).reshape(m, -1)
                          ).reshape(m, n, n)
    H = np.fft.fftn(cone(cone_kind, m, n, width, SUM_BINS * 4e-12))
    v = np.real(np.fft.ifftn(np.fft.fftn(padded) * np.conj(H) / (np.abs(H) ** 2 + 1 / snr)))
    vol = np.maximum((to_z @ v[:m, :n, :n].reshape(m, -1)).reshape(m, n, n), 0)
    return vol[:, :, ::-1]


def display_crop(vol: np.ndarray, stem: str, width: float, nt_native: int) -> np.ndarray:
    """The published display's depth crop (as tests/reference/lct_published.py takes it)."""
    from reference.lct_published import PUBLISHED_Z_OFFSET

    m = vol.shape[0]
    z0 = round(PUBLISHED_Z_OFFSET[stem] / SUM_BINS)
    rng = nt_native * C_PUBLISHED * 4e-12
    return vol[z0:z0 + round(m * 2 * width / (rng / 2))]


def split_half_rows(files) -> list[dict]:
    from reference.lct_published import PUBLISHED_Z_OFFSET, published_lct

    rows = []
    for f in files:
        rect, width = load(f)
        kw = dict(diffuse="diffuse" in f.stem, z_offset=PUBLISHED_Z_OFFSET.get(f.stem))
        rng = np.random.default_rng(0)
        a = rng.binomial(rect.astype(np.int64), 0.5).astype(np.float64)
        full, fa, fb = (published_lct(x, width, **kw)[0].max(axis=0) for x in (rect, a, rect - a))
        rows.append({"kind": "split_half", "capture": f.stem,
                     "ncc_front_halves": scores(fa, fb)[0],
                     "ncc_detail_halves": scores(fa, fb)[1],
                     "ncc_detail_half_a_whole": scores(fa, full)[1],
                     "ncc_detail_half_b_whole": scores(fb, full)[1]})
        print(rows[-1], flush=True)
    return rows


def load(path: Path) -> tuple[np.ndarray, float]:
    import scipy.io

    d = scipy.io.loadmat(path)
    return np.asarray(d["rect_data"], np.float64), float(d["width"].ravel()[0])


def morph_rows(path: Path) -> list[dict]:
    import clnlos
    from reference.lct_published import PUBLISHED_Z_OFFSET, published_lct

    rect, width = load(path)
    stem, nt = path.stem, rect.shape[2]
    ref = published_lct(rect, width, diffuse=True, z_offset=PUBLISHED_Z_OFFSET[stem])[0]
    front_ref = ref.max(axis=0)
    rec = clnlos.reconstruct(path, method="lct")
    snr_clnlos = float(rec.params["inversion_snr_used"])
    snr_published = 0.08 * (2 * rect.shape[0]) ** 2  # 0.08 for the published shell's norm
    clnlos_steps = dict(falloff=float(rec.params["falloff_used"]), floor=True,
                        weight="clnlos", resampling="clnlos", cone_kind="clnlos")
    published_steps = dict(falloff=4.0, floor=False, weight="published",
                           resampling="published", cone_kind="published")
    cases = [("clnlos", "clnlos stages (against clnlos.reconstruct)", clnlos_steps,
              snr_clnlos)]
    for snr in (snr_clnlos, snr_published):
        cases += [("clnlos", "clnlos stages", clnlos_steps, snr),
                  ("clnlos", "no floor subtraction", clnlos_steps | {"floor": False}, snr),
                  ("clnlos", "published t grid linspace(0,1,M)",
                   clnlos_steps | {"weight": "published"}, snr),
                  ("clnlos", "published resampling", clnlos_steps | {"resampling": "published"},
                   snr),
                  ("clnlos", "falloff 4", clnlos_steps | {"falloff": 4.0}, snr),
                  ("clnlos", "cone half a pitch off", clnlos_steps | {"cone_kind": "half_pitch"},
                   snr),
                  ("clnlos", "cone half a pitch off, published pitch",
                   clnlos_steps | {"cone_kind": "half_pitch_published_pitch"}, snr),
                  ("clnlos", "published cone (+ nearest v bin)",
                   clnlos_steps | {"cone_kind": "published"}, snr)]
    cases += [("published", "published stages", published_steps, snr_published),
              ("published", "floor subtracted", published_steps | {"floor": True},
               snr_published),
              ("published", "clnlos t grid (bin centres)",
               published_steps | {"weight": "clnlos"}, snr_published),
              ("published", "clnlos resampling", published_steps | {"resampling": "clnlos"},
               snr_published),
              ("published", "falloff 2", published_steps | {"falloff": 2.0}, snr_published),
              ("published", "clnlos cone", published_steps | {"cone_kind": "clnlos"},
               snr_published)]
    rows = []
    for base, variant, steps, snr in cases:
        vol = stages(rect, width, snr=snr, **steps)
        target = front_ref
        if "against" in variant:  # clnlos's volume ends at the capture's last light
            target = rec.volume.max(axis=0)[::-1, :]
            end = rec.params.get("depth_end_m")
            if end is not None:
                vol[round(end / (rec.bin_width_s * clnlos.C0 / 2)):] = 0
        full = scores(vol.max(axis=0), target)
        crop = scores(display_crop(vol, stem, width, nt).max(axis=0), front_ref)
        rows.append({"kind": "morph", "capture": stem, "base": base, "variant": variant,
                     "lightcone_snr": snr, **{k: v for k, v in steps.items()},
                     "ncc_front_full": full[0], "ncc_detail_full": full[1],
                     "ncc_front_crop": crop[0], "ncc_detail_crop": crop[1]})
        print(rows[-1], flush=True)
    return rows


def registration_rows() -> list[dict]:
    from clnlos.inverse.lct import LCT
    from clnlos.io.formats.mat import lct_rect_data
    from reference.lct_published import published_lct
    from reference.scene_ref import points_transient, scan_centres

    n, width, nt, dt = 16, 0.5, 128, 32e-12
    iy, ix = 9, 6
    c = scan_centres(n, width)
    tau = points_transient([(c[ix], c[iy], 0.35)], [1.0], nt, n, width, dt)
    ours = np.asarray(LCT((nt, n, n), bin_width_s=dt, scan_width_m=width, falloff=4,
                          snr=1e4)(tau.astype(np.float32)), np.float64).max(axis=0)[::-1, :]
    theirs = published_lct(lct_rect_data(tau), width / 2, diffuse=True, bin_width_s=dt,
                           downsample=0, z_trim=0, snr=1e4)[0].max(axis=0)
    rows = []
    for name, front in (("lct", ours), ("published", theirs)):
        j, i = n - 1 - iy, ix  # the point's pixel in the display orientation
        w = front[j - 2:j + 3, i - 2:i + 3]
        yy, xx = np.mgrid[-2:3, -2:3]
        rows.append({"kind": "registration", "pipeline": name,
                     "centroid_row_px": float((w * yy).sum() / w.sum()),
                     "centroid_col_px": float((w * xx).sum() / w.sum())})
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    from clnlos.bench.oracle import write_rows

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(ROOT.parent / "shared" / "data"))
    args = ap.parse_args(argv)
    files = sorted(Path(args.shared, "lct").glob("*.mat"))
    diffuse = [f for f in files if f.stem == "data_diffuse_s"]
    if not diffuse:
        print(f"no data_diffuse_s.mat in {args.shared}/lct")
        return 2
    rows = registration_rows() + split_half_rows(files) + morph_rows(diffuse[0])
    write_rows(rows, RESULTS / "lct_detail_study")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

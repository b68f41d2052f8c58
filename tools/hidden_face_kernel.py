#!/usr/bin/env python3
"""Which hidden-face kernel deconvolves better: CDT's Phi * Phi or the far-target Eq. 8 one
(clnlos.forward.blur.eq8_psf)?

    .venv/bin/python tools/hidden_face_kernel.py [--shared ../shared/data]

Simulated: an exact Eq. 8 capture of Lambertian points behind the CDT slab (float64 numpy,
tests/reference/eq8_ref.py: r1 and r2 independent, bistatic paths), against
(a) the forward model K * I_c of each kernel (I_c the hidden-face confocal transient) and
(b) the Wiener deconvolution of the capture by each kernel against I_c (both blurred by a
Gaussian of SMOOTH_BINS in time), on scan points away from the face grid's border.
Real: the shared captures letters_ut and letter_s reconstructed with each kernel (published
parameters, examples/cdt_*.toml): MIP contrast (Otsu foreground / background mean) and
sharpness (mean squared gradient / mean square). Writes tools/results/hidden_face_kernel.json.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
OUT = ROOT / "tools" / "results" / "hidden_face_kernel.json"
SMOOTH_BINS = 2.0  # time blur (std, bins) of deconvolution and truth before comparing
WIENER_SNRS = (1e2, 1e3, 1e4, 1e5, 1e6)  # deconvolutions compared at each (best kept)
# Simulated: 3 Lambertian points at depth z (lateral offsets POINTS_XY, weights WEIGHTS)
# behind the CDT slab, a 0.2 m face grid of 6 mm cells, 16 ps bins, errors over the scan
# points within INNER_M of the centre; and one point on axis, tau at PAIR_R0 by the
# brute-force pair sum (no face border).
DEPTHS = ((0.2, 160), (0.5, 320))  # (z in m, bins)
GRID = dict(n=33, pitch_m=0.006, bin_width_s=16e-12, phi_half=10)
POINTS_XY = ((0.0, 0.0), (0.04, -0.02), (-0.05, 0.03))
WEIGHTS = (1.0, 0.7, 0.5)
INNER_M = 0.06
PAIR_R0 = ((0.0, 0.0), (0.0, 0.04), (0.0, 0.08))
CAPTURES = (("letters_ut.mat", "cdt_letters_ut.toml"), ("letter_s.mat", "cdt_letter_s.toml"))


def _ref():
    sys.path.insert(0, str(ROOT))
    from tests.reference import eq8_ref

    return eq8_ref


def _phi(nt, queue):
    """Phi per face cell, centred [lag, 2 h + 1, 2 h + 1], float64."""
    from clnlos.diffusion import diffusion_psf
    from clnlos.physics.slab import CDT_SLAB

    g, h = GRID, GRID["phi_half"]
    phi = diffusion_psf(CDT_SLAB, nt=nt, bin_width_s=g["bin_width_s"], ny=2 * h + 2,
                        nx=2 * h + 2, pitch_m=g["pitch_m"], dtype=np.float64, queue=queue)
    return _ref().centred(phi, h)


def _rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def _kernel(name, shape, queue):
    from clnlos.forward.blur import confocal_psf, eq8_psf
    from clnlos.physics.slab import CDT_SLAB

    kw = dict(bin_width_s=GRID["bin_width_s"], pitch_m=GRID["pitch_m"], dtype=np.float64,
              queue=queue)
    return (confocal_psf(CDT_SLAB, shape, **kw).get() if name == "cdt"
            else eq8_psf(CDT_SLAB, shape, **kw))


def simulated_depth(z: float, nt: int, queue) -> dict:
    """Both kernels against the Eq. 8 capture of the point scene at depth ``z``."""
    import pyopencl.array as cla
    from scipy.ndimage import gaussian_filter1d
    from scipy.signal import fftconvolve

    from clnlos.forward.blur import KERNELS, slab_blur
    from clnlos.physics.slab import CDT_SLAB

    ref, g = _ref(), GRID
    n, phi = g["n"], _phi(nt, queue)
    pts = [(x, y, z) for x, y in POINTS_XY]
    kw = dict(face_n=n, face_pitch_m=g["pitch_m"], nt=nt, bin_width_s=g["bin_width_s"])
    tau = ref.eq8_capture(pts, WEIGHTS, phi_centred=phi, **kw)
    ic = ref.confocal_transient(pts, WEIGHTS, **kw)
    f = ref.face_grid(n, g["pitch_m"])
    inner = np.hypot(f[:, None], f[None, :]) < INNER_M
    truth = gaussian_filter1d(ic, SMOOTH_BINS, axis=0)[:, inner]
    pair = {h: [ref.pair_sum_transient((0.0, 0.0, z), r0, phi_centred=phi,
                                       pitch_m=g["pitch_m"], bin_width_s=g["bin_width_s"],
                                       hidden=h) for r0 in PAIR_R0]
            for h in ("exact", "midpoint", "cdt")}
    out = {"pair_midpoint_vs_exact": [_rel(a, b) for a, b in zip(pair["midpoint"],
                                                                 pair["exact"], strict=True)],
           "pair_cdt_vs_exact": [_rel(a, b) for a, b in zip(pair["cdt"], pair["exact"],
                                                            strict=True)]}
    shape = (nt, n, n)
    for name in KERNELS:
        kc = ref.centred(_kernel(name, shape, queue)[:nt], n - 1)
        model = fftconvolve(ic, kc, mode="full", axes=(0, 1, 2))[:nt, n - 1:2 * n - 1,
                                                                 n - 1:2 * n - 1]
        m_in, t_in = model[:, inner], tau[:, inner]
        row = {"forward_rel_l2": _rel(m_in, t_in),
               "forward_shape_rel_l2": _rel(m_in / m_in.sum(0), t_in / t_in.sum(0))}
        best = None
        for snr in WIENER_SNRS:
            w = slab_blur(CDT_SLAB, shape, bin_width_s=g["bin_width_s"], pitch_m=g["pitch_m"],
                          mode="wiener", snr=snr, kernel=name, dtype=np.float64, queue=queue)
            x = w(cla.to_device(w.queue, np.ascontiguousarray(tau))).get()
            x = gaussian_filter1d(x, SMOOTH_BINS, axis=0)[:, inner]
            c = _corr(x, truth)
            if best is None or c > best[1]:
                best = (snr, c, _rel(x * (x * truth).sum() / (x * x).sum(), truth))
        row.update(deconv_snr=best[0], deconv_corr=best[1], deconv_rel_l2=best[2])
        out[name] = row
    print(f"simulated z = {z} m: {out}", flush=True)
    return out


def simulated(queue) -> dict:
    return {f"z_{z:g}m": simulated_depth(z, nt, queue) for z, nt in DEPTHS}


def _mip_metrics(mip: np.ndarray) -> dict:
    from clnlos.study.score.metrics import otsu_threshold

    m = mip / max(float(mip.max()), 1e-30)
    th = otsu_threshold(m)
    fg, bg = m[m > th], m[m <= th]
    gy, gx = np.gradient(m)
    return {"contrast": float(fg.mean() / max(bg.mean(), 1e-30)),
            "sharpness": float((gy ** 2 + gx ** 2).mean() / (m ** 2).mean()),
            "foreground_fraction": float(fg.size / m.size)}


def real(shared: Path) -> dict:
    import clnlos.forward.blur as blur
    import clnlos.inverse.pipeline as rec
    from clnlos.config import ReconstructionConfig
    from clnlos.io.files import read_capture
    from clnlos.runtime.caches import PIPELINES

    out = {}
    original = blur.slab_blur
    for cap_name, cfg_name in CAPTURES:
        cap = read_capture(shared / "cdt" / cap_name)
        cfg = ReconstructionConfig.from_toml(ROOT / "examples" / cfg_name).validate()
        mips = {}
        for name in blur.KERNELS:
            patched = functools.partial(original, kernel=name)
            rec.slab_blur = blur.slab_blur = patched
            PIPELINES.clear()  # the pipeline holds the deconvolution it was built with
            try:
                mips[name] = rec.reconstruct(cap, cfg).volume.max(axis=0).astype(np.float64)
            finally:
                rec.slab_blur = blur.slab_blur = original
        out[cap_name] = {name: _mip_metrics(m) for name, m in mips.items()}
        out[cap_name]["mip_correlation"] = _corr(mips["cdt"], mips["eq8"])
        print(f"real {cap_name}: {out[cap_name]}", flush=True)
    return out


def main(argv=None) -> int:
    from clnlos.io.outputs import provenance, stamp, write_group
    from clnlos.runtime.device import get_queue

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shared", default=str(SHARED), help="the shared data folder")
    shared = Path(ap.parse_args(argv).shared)
    q = get_queue(None)
    res = {"simulated": simulated(q),
           "sim_setup": {**GRID, "depths": DEPTHS, "points_xy": POINTS_XY, "weights": WEIGHTS,
                         "inner_m": INNER_M, "pair_r0": PAIR_R0, "smooth_bins": SMOOTH_BINS}}
    if (shared / "cdt").is_dir():
        res["real"] = real(shared)
    else:
        print(f"hidden_face_kernel: {shared / 'cdt'} not present, real captures skipped",
              file=sys.stderr)
    with write_group([OUT]) as (tmp,):
        tmp.write_text(json.dumps(stamp({"provenance": provenance(device=q.device.name.strip()),
                                         **res}), indent=1) + "\n")
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

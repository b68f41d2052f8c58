"""How the legibility judge reconstructs a capture: the same recipe for its twins, the real
captures and a user's file.

A capture is reconstructed with JUDGE_METHOD and the SNR rule JUDGE_SNR_RULE (the
closed-form inversion: three per capture in well under a second), its scan points summed in
k x k blocks to at most JUDGE_MAX_POINTS a side (:func:`binned_laterally`) and its time axis
rebinned to at most JUDGE_MAX_BINS, together with two binomial halves of its photons
(:func:`judge_reconstructions`). What the recipe takes from elsewhere
(:func:`judge_config`) comes from the capture file's contents (its geometry, its recorded
slab, what its format records) and from the user's options (USER_FIELDS of a
:class:`~clnlos.config.ReconstructionConfig`: the geometry a file may not store, the slab,
the window); never from the file's name. A volume (any method, grid or size) is judged by
its maximum-intensity projection averaged in k x k blocks to at most JUDGE_MAX_POINTS a side
(:func:`clnlos.study.judge.features.pooled`), the grid the capture model's
reconstructions have.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from clnlos.config import ReconstructionConfig
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.preprocessing import bins_for, preprocess_bins, setup_slab
from clnlos.inverse.thinning import thin_counts
from clnlos.io.capture import without_direct
from clnlos.study.judge.features import POOLED_POINTS, block_factor

JUDGE_METHOD = "lct"      # the judge reconstructs a capture (and its halves) this way: the
JUDGE_SNR_RULE = "gcv"    # closed-form inversion, 3 per capture in well under a second
JUDGE_MAX_BINS = 256      # a capture keeps at most this many time bins ...
JUDGE_MAX_POINTS = POOLED_POINTS  # ... and this many scan points a side (k x k summed)
# what the judge takes from the user's options: where and how the capture was taken (what a
# file may not store) and the slab; the method and its SNRs are the recipe's
USER_FIELDS = ("scan_width_m", "bin_width_s", "start_s", "direct_cut_s", "max_path_m", "bins",
               "slab", "n_dipoles")


def recipe_settings() -> dict:
    """The recipe as a judge records it."""
    return {"method": JUDGE_METHOD, "snr_rule": JUDGE_SNR_RULE, "max_bins": JUDGE_MAX_BINS,
            "max_points": JUDGE_MAX_POINTS}


def judge_config(capture, options: ReconstructionConfig | None = None,
                 recipe: dict | None = None, *, no_slab: bool = False) -> ReconstructionConfig:
    """How the judge reconstructs ``capture``: the recipe's method and SNR rule; from
    ``options`` (the user's config, may be None) the USER_FIELDS it sets; the time axis
    rebinned to at most the recipe's ``max_bins`` where the options set no ``bins``; the
    slab the options name, else the one the capture recorded (none with ``no_slab``)."""
    recipe = recipe or recipe_settings()
    kw = {} if options is None else {f: getattr(options, f) for f in USER_FIELDS
                                     if getattr(options, f) is not None}
    nt = np.asarray(capture.transient).shape[0]
    most = int(recipe.get("max_bins", JUDGE_MAX_BINS))
    if "bins" not in kw and nt > most:
        kw["bins"] = most
    cfg = ReconstructionConfig(method=recipe["method"], snr_rule=recipe["snr_rule"],
                               **kw).validate()
    if no_slab:
        return cfg.replace(slab=None)
    return cfg if cfg.slab is not None else setup_slab(cfg, capture)[0]


def capture_descriptors(capture, config: ReconstructionConfig) -> dict:
    """What the judge's domain checks of a capture as the recipe reconstructs it
    (:data:`clnlos.study.judge.domain.DESCRIPTORS`): its scan points per side, photons per
    scan point (its counts after the direct reflection's cut, over its points), the
    reconstruction's time bin (s: the kept window over the bins it is rebinned to; None
    where the capture's bin width is unknown), the scan width (m) and the slab's thickness
    (m, 0 without one)."""
    t = np.asarray(without_direct(capture, config.direct_cut_s, bin_width_s=config.bin_width_s,
                                  start_s=config.start_s)[0].transient)
    points = int(max(t.shape[1:]))
    bw = config.bin_width_s or capture.bin_width_s
    start = config.start_s if config.start_s is not None else capture.start_s
    recon_bw = None
    if bw is not None:
        keep, after = preprocess_bins(t.shape[0], bw, start, config.max_path_m,
                                      bins_for(config, t.shape[0], bw, start))
        recon_bw = keep * bw / after
    return {"points": points,
            "photons_per_point": float(np.clip(t, 0, None).sum(dtype=np.float64))
            / (t.shape[1] * t.shape[2]),
            "bin_width_s": recon_bw,
            "scan_width_m": config.scan_width_m or capture.scan_width_m,
            "slab_thickness_m": 0.0 if config.slab is None else float(config.slab.thickness_m)}


def binned_laterally(capture, most: int = JUDGE_MAX_POINTS):
    """The capture with its scan points summed in k x k blocks (photon counts kept), k the
    smallest integer that leaves at most ``most`` points per side (unchanged for k = 1); the
    time shifts a reader moved its columns by (:attr:`clnlos.io.capture.Capture.
    time_shift_bins`, the f-k release's), averaged over each block."""
    t = np.asarray(capture.transient)
    k = block_factor(t.shape[1:], most)
    if k <= 1:
        return capture
    ny, nx = (t.shape[1] // k) * k, (t.shape[2] // k) * k
    b = t[:, :ny, :nx].reshape(t.shape[0], ny // k, k, nx // k, k).sum(axis=(2, 4))
    w = None if capture.scan_width_m is None else capture.scan_width_m * nx / t.shape[2]
    h = None if capture.scan_height_m is None else capture.scan_height_m * ny / t.shape[1]
    shifts = capture.time_shift_bins
    if shifts is not None:
        shifts = np.asarray(shifts, np.float64)[:ny, :nx].reshape(
            ny // k, k, nx // k, k).mean(axis=(1, 3))
    return replace(capture, transient=b.astype(t.dtype), scan_width_m=w, scan_height_m=h,
                   time_shift_bins=shifts)


def judge_reconstructions(capture, config: ReconstructionConfig, device=None,
                          seed: int | None = None):
    """(full, half 1, half 2) volumes of a photon-count capture with ``config``: the capture
    and its two binomial halves (:func:`clnlos.inverse.thinning.thin_counts`, seeded: the
    same file gives the same halves)."""
    kw = {} if seed is None else {"seed": seed}
    h1, h2 = thin_counts(np.asarray(capture.transient), **kw)
    return tuple(reconstruct(replace(capture, transient=y), config, device=device).volume
                 for y in (capture.transient, h1, h2))

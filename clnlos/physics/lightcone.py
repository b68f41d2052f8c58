"""The confocal light cone as a PSF on the v = t^2 grid (pure numpy, float64): the one
builder that the light-cone transform (:mod:`clnlos.inverse.lct`) and the light-cone
transport of the iterative method (:mod:`clnlos.forward.transport`) share.

In v = (c t / 2)^2 a point at depth z seen from a scan point at lateral offset d arrives at
v = z^2 + |d|^2: the cone is a shift of |d|^2 along v, the same at every depth, so the
transport is a 3D convolution. On a grid of v bins of width dv (m^2) the shift is
s = |d|^2 / dv bins, split linearly between bins floor(s) and floor(s) + 1.
"""

from __future__ import annotations

import numpy as np


def lightcone_psf_grid(shift_bins: np.ndarray, pad_t: int, k_max: int,
                       weights: np.ndarray | None = None) -> np.ndarray:
    """h[k, y, x] on a (pad_t, ny, nx) grid: weight ``weights[y, x]`` (default 1) per lateral
    cell (y, x) at the v-shift ``shift_bins[y, x]`` (bins, >= 0), split linearly between bins
    floor(s) and floor(s) + 1; weight landing past bin ``k_max`` is dropped (float64, not
    normalised)."""
    s = np.asarray(shift_bins, np.float64)
    cell = np.ones(s.shape) if weights is None else np.asarray(weights, np.float64)
    k0 = np.floor(s).astype(np.int64)
    f = s - k0
    h = np.zeros((int(pad_t),) + s.shape)
    yy, xx = np.indices(s.shape)
    for kk, w in ((k0, (1.0 - f) * cell), (k0 + 1, f * cell)):
        ok = kk <= k_max
        np.add.at(h, (kk[ok], yy[ok], xx[ok]), w[ok])
    return h

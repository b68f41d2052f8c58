"""Measured features of a reconstruction that the legibility judge reads (pure numpy / scipy).

Every feature is a ratio of quantities measured on the image itself, so it does not change
when the target is moved or scaled inside the scan (up to the resampling of its edges), nor
with the albedo scale or the grid: the judge must carry from the study's glyph scale to real
captures whose letters fill the scan. From a maximum-intensity projection m [y, x] (clipped
at 0, over its maximum), split by its Otsu threshold into foreground F and background B:

* ``contrast``: (mean_F - mean_B) / (mean_F + mean_B), in [0, 1] (Michelson contrast of the
  two classes; the share of the scan the target covers does not enter);
* ``foreground_cv``: std_F / mean_F, the spread of the foreground (noise: spikes; a glyph:
  strokes of one level);
* ``background_level``: mean_B / mean_F;
* ``major_parts``: the share of the foreground's intensity in its 8-connected parts that
  each hold at least MAJOR_PART of its cells (noise: many small parts; letters, bars or a
  dot chart: a few large ones);
* ``solidity``: the foreground's cells over the area of their convex hull (a blob, a
  specular glint: near 1; strokes: less; noise scattered over the scan: little);
* ``peak_share``: the share of the foreground's intensity in its brightest 1/8 of cells (a
  specular glint: most of it; a glyph: about 1/8 or a little more);
* ``blob_fit``: the Pearson r over the scan cells of m with the Gaussian blob of m's own
  centre and spread, g(p) = exp(-(p - c)^T S^-1 (p - c) / 2), c and S the mean and
  covariance of the foreground's cell positions p weighted by m - mean_B (a glint or an
  unresolved target: near 1; letters, bars, dots: less).

From the MIPs m1, m2 of the reconstructions of two binomial halves of the photons
(:func:`clnlos.inverse.thinning.thin_counts`, independent Poisson captures of half the
mean), what only a capture can give and no ground truth needs:

* ``half_agreement``: the Pearson correlation r(m1, m2) over the scan cells (the signal
  that both halves see over the noise neither shares: 0 for noise, 1 for a noiseless image);
* ``half_overlap``: the Dice coefficient 2 |M1 & M2| / (|M1| + |M2|) of their Otsu masks.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull

from clnlos.inverse.reproducibility import otsu_threshold

MIP_FEATURES = ("contrast", "foreground_cv", "background_level", "major_parts", "solidity",
                "peak_share", "blob_fit")
HALF_FEATURES = ("half_agreement", "half_overlap")
CAPTURE_FEATURES = MIP_FEATURES + HALF_FEATURES
# the shipped judge's: what tells an image from its noise, whatever the target's shape (the
# shape's own features -- solidity, peak share, blob fit -- did not carry to a kind of
# target held out of the training: trained without charts, the capture model scored 0.67
# balanced accuracy on them, 0.90 with the halves' agreement alone)
NOISE_MIP_FEATURES = ("contrast", "background_level", "foreground_cv", "major_parts")
NOISE_CAPTURE_FEATURES = HALF_FEATURES + NOISE_MIP_FEATURES
PEAK_SHARE_CELLS = 1 / 8  # the brightest share of the foreground's cells in peak_share
MAJOR_PART = 1 / 20       # a major part holds at least this share of the foreground's cells
EIGHT_CONNECTED = np.ones((3, 3), bool)
POOLED_POINTS = 32        # a volume's MIP is averaged to at most this many cells a side


def mip_of(volume) -> np.ndarray:
    """The maximum-intensity projection [y, x] of a volume [z, y, x] (or an image [y, x]),
    clipped at 0 and over its maximum (float64; all zero stays zero)."""
    a = np.asarray(volume, np.float64)
    m = np.clip(a.max(axis=0) if a.ndim == 3 else a, 0.0, None)
    top = float(m.max()) if m.size else 0.0
    return m / top if top > 0 else m


def block_factor(shape, most: int = POOLED_POINTS) -> int:
    """The smallest k that leaves at most ``most`` cells per side of ``shape`` in k x k
    blocks."""
    return max(1, -(-max(int(s) for s in shape) // most))


def pooled(image, most: int = POOLED_POINTS) -> np.ndarray:
    """An image [y, x] averaged in k x k blocks (:func:`block_factor`; the last rows and
    columns that fill no block dropped): the grid the capture model's reconstructions have."""
    m = np.asarray(image, np.float64)
    k = block_factor(m.shape, most)
    if k <= 1:
        return m
    ny, nx = (m.shape[0] // k) * k, (m.shape[1] // k) * k
    return m[:ny, :nx].reshape(ny // k, k, nx // k, k).mean(axis=(1, 3))


def foreground(mip: np.ndarray) -> np.ndarray:
    """The Otsu foreground of a MIP (all false for a constant image)."""
    m = np.asarray(mip, np.float64)
    if not m.size or float(m.max()) <= float(m.min()):
        return np.zeros(m.shape, bool)
    return m > otsu_threshold(m)


def mip_features(mip) -> dict[str, float]:
    """The MIP's features (module docstring) of an image [y, x] or a volume [z, y, x]."""
    m = mip_of(mip)
    fg = foreground(m)
    if not fg.any() or fg.all():
        return {"contrast": 0.0, "foreground_cv": 0.0, "background_level": 1.0,
                "major_parts": 0.0, "solidity": 0.0, "peak_share": 1.0, "blob_fit": 0.0}
    f, b = m[fg], m[~fg]
    mf, mb = float(f.mean()), float(b.mean())
    labels, n = ndimage.label(fg, structure=EIGHT_CONNECTED)
    index = np.arange(1, n + 1)
    cells = ndimage.sum(fg, labels, index=index)
    mass = ndimage.sum(m, labels, index=index)
    k = max(1, int(round(PEAK_SHARE_CELLS * f.size)))
    top = np.sort(f)[-k:]
    return {"contrast": (mf - mb) / (mf + mb),
            "foreground_cv": float(f.std() / mf),
            "background_level": mb / mf,
            "major_parts": float(mass[cells >= MAJOR_PART * f.size].sum() / f.sum()),
            "solidity": solidity(fg),
            "peak_share": float(top.sum() / f.sum()),
            "blob_fit": blob_fit(m, fg, mb)}


def blob_fit(mip: np.ndarray, fg: np.ndarray, floor: float) -> float:
    """Pearson r of a MIP with the Gaussian of its own centre and spread (the weights
    m - floor over the foreground ``fg``; module docstring); 0 without weight."""
    m = np.asarray(mip, np.float64)
    w = np.where(fg, np.clip(m - floor, 0.0, None), 0.0)
    total = float(w.sum())
    if total <= 0:
        return 0.0
    yy, xx = np.mgrid[:m.shape[0], :m.shape[1]].astype(np.float64)
    cy, cx = float((w * yy).sum()) / total, float((w * xx).sum()) / total
    dy, dx = yy - cy, xx - cx
    cov = np.array([[(w * dx * dx).sum(), (w * dx * dy).sum()],
                    [(w * dx * dy).sum(), (w * dy * dy).sum()]]) / total
    inv = np.linalg.inv(cov + 1e-6 * np.eye(2))
    g = np.exp(-0.5 * (inv[0, 0] * dx * dx + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy * dy))
    return pearson_r(m, g)


def solidity(mask: np.ndarray) -> float:
    """Cells of a mask over the area of the convex hull of those cells (squares, in cells)."""
    iy, ix = np.nonzero(mask)
    corners = np.array([(0, 0), (0, 1), (1, 0), (1, 1)], float)
    pts = (np.stack([ix, iy], axis=1)[:, None, :] + corners[None]).reshape(-1, 2)
    return float(len(iy) / ConvexHull(pts).volume)


def pearson_r(a, b) -> float:
    """Pearson correlation of two images over their cells (0 where either is constant)."""
    x = np.asarray(a, np.float64).ravel()
    y = np.asarray(b, np.float64).ravel()
    x, y = x - x.mean(), y - y.mean()
    d = float(np.sqrt((x * x).sum() * (y * y).sum()))
    return float((x * y).sum() / d) if d > 0 else 0.0


def dice(a, b) -> float:
    """Dice coefficient 2 |A & B| / (|A| + |B|) of two masks (0 when both are empty)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    s = int(a.sum() + b.sum())
    return 2.0 * float((a & b).sum()) / s if s else 0.0


def half_features(half1, half2) -> dict[str, float]:
    """The agreement of the reconstructions (volumes or MIPs) of two photon halves."""
    m1, m2 = mip_of(half1), mip_of(half2)
    return {"half_agreement": pearson_r(m1, m2),
            "half_overlap": dice(foreground(m1), foreground(m2))}


def capture_features(full, half1, half2) -> dict[str, float]:
    """Every feature of a capture: the full reconstruction's MIP and its halves' agreement."""
    return {**mip_features(full), **half_features(half1, half2)}


def feature_matrix(rows: list[dict], names) -> np.ndarray:
    """[n, k] float64 of the named features of each row (a dict of features)."""
    return np.array([[float(r[f]) for f in names] for r in rows], np.float64).reshape(
        len(rows), len(names))

"""No-reference quality metrics of a reconstruction (computed from the volume alone), their
validation against ground truth, and the three clarity labels.

Metrics (higher = better; each of a max-intensity projection ``mip`` [y, x] normalised to
its maximum, some also of the depth map of the brightest voxel per column):

* ``fft_clarity`` (the seed's, :mod:`clnlos.study.score.clarity`): log10 of the variance of the
  Hann-windowed high-frequency band 0.25 <= |k|/k_Nyquist <= 1.
* ``otsu_separability``: Otsu's effectiveness eta = sigma_between^2 / sigma_total^2 of the
  MIP's histogram (0..1): 1 for a two-level image (an object on a clean background).
* ``central_energy``: 1 - the fraction of the MIP's energy within ``BORDER_CELLS`` of the
  scan border. Light from the hidden side is measured only over the aperture; near its
  border the light cone is sampled on one side only and the slab deconvolution is least
  reliable (the blur reaches past the scan), so reconstructions that put their energy there
  are artefacts (a corner spot where nothing was seen is the typical failure).
* ``depth_coherence``: 1 / (1 + mean |depth difference| in cm between neighbouring
  foreground pixels): a surface is continuous, noise is not.
* ``nr_clarity`` = otsu_separability x central_energy: the default label metric.

Labels: 1 clear, 2 medium, 3 fuzzy, cut at the dataset quantiles that reproduce the seed's
split of 193 / 514 / 293 in 1000 (:mod:`clnlos.study.score.clarity`).
"""

from __future__ import annotations

import numpy as np

from clnlos.study.score.clarity import clarity_score
from clnlos.study.score.metrics import otsu_threshold

BORDER_CELLS = 3
METRICS = ("nr_clarity", "otsu_separability", "central_energy", "depth_coherence",
           "fft_clarity")
DEFAULT_LABEL_METRIC = "nr_clarity"


def _normalised(mip: np.ndarray) -> np.ndarray:
    a = np.asarray(mip, np.float64)
    m = a.max()
    return a / m if m > 0 else a


def otsu_separability(mip: np.ndarray) -> float:
    v = _normalised(mip).ravel()
    if v.var() == 0:
        return 0.0
    t = otsu_threshold(v)
    lo, hi = v[v <= t], v[v > t]
    if lo.size == 0 or hi.size == 0:
        return 0.0
    w0, w1 = lo.size / v.size, hi.size / v.size
    return float(w0 * w1 * (hi.mean() - lo.mean()) ** 2 / v.var())


def central_energy(mip: np.ndarray, border: int = BORDER_CELLS) -> float:
    a = _normalised(mip)
    total = a.sum()
    if total <= 0:
        return 0.0
    inner = a[border:-border, border:-border].sum() if min(a.shape) > 2 * border else 0.0
    return float(inner / total)


def depth_coherence(mip: np.ndarray, depth_m: np.ndarray) -> float:
    a = _normalised(mip)
    fg = a > otsu_threshold(a)
    diffs = []
    for axis in (0, 1):
        n = fg.shape[axis]
        both = np.take(fg, range(n - 1), axis=axis) & np.take(fg, range(1, n), axis=axis)
        diffs.append(np.abs(np.diff(depth_m, axis=axis))[both])
    d = np.concatenate(diffs)
    return float(1.0 / (1.0 + 100.0 * np.mean(d))) if d.size else 0.0


def quality_metrics(volume: np.ndarray, voxel_depth_m: float) -> dict[str, float]:
    """Every no-reference metric of a volume [z, y, x] (see module docstring)."""
    mip = volume.max(axis=0)
    depth = (np.argmax(volume, axis=0) + 0.5) * voxel_depth_m
    eta = otsu_separability(mip)
    central = central_energy(mip)
    fft = clarity_score(_normalised(mip))
    return {"nr_clarity": eta * central, "otsu_separability": eta, "central_energy": central,
            "depth_coherence": depth_coherence(mip, depth),
            "fft_clarity": float(np.log10(max(fft, 1e-30)))}


def pearson(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if a.size < 3 or a.std() == 0 or b.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def validate_metrics(metric_values: dict[str, np.ndarray], truth: dict[str, np.ndarray]
                     ) -> dict[str, dict[str, float]]:
    """Pearson r of every metric with every ground-truth measure over the dataset."""
    return {m: {t: pearson(v, tv) for t, tv in truth.items()}
            for m, v in metric_values.items()}

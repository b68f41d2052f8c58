"""Image clarity from the Fourier spectrum (seed section 3.2) and the three clarity labels.

score(img) = variance of the high-frequency band of img / max(img) (Hann-windowed, so the
             border's periodic wrap adds nothing): the image filtered to
             0.25 <= |k| / k_Nyquist <= 1 (radial), whose variance is, by Parseval,
             sum over the band of |F|^2 / N^2 (the band holds no DC, so its mean is 0).
A sharper image keeps more energy at high frequencies, and a blur (any low-pass filter)
attenuates every frequency, so the score falls monotonically as the image blurs.

Labels: 1 clear, 2 clearer (medium), 3 fuzzy, by thresholds on the score taken from the
dataset itself at the quantiles that reproduce the seed's split of 193 / 514 / 293 in 1000:
score >= q(0.807) -> 1, q(0.293) <= score < q(0.807) -> 2, score < q(0.293) -> 3. Cut so,
the labels' mix is the seed's by construction, and their agreement with the seed's
published labels is not evidence. :func:`truth_thresholds` cuts the same score where its
labels best match the study's own ground truth instead (each glyph reconstruction's
legibility class): the cut the study's agreement with the seed's labels is also reported
at.
"""

from __future__ import annotations

import numpy as np

BAND = (0.25, 1.0)
SEED_SPLIT = (0.193, 0.514, 0.293)  # fractions labelled 1, 2, 3 in the seed's 1000 images


def clarity_score(img: np.ndarray, band: tuple[float, float] = BAND) -> float:
    a = np.asarray(img, np.float64)
    m = np.abs(a).max()
    if m == 0:
        return 0.0
    # a Hann window keeps the periodic wrap of the image border out of the high band
    win = np.outer(np.hanning(a.shape[0] + 2)[1:-1], np.hanning(a.shape[1] + 2)[1:-1])
    F = np.fft.fft2(a / m * win)
    ky = np.fft.fftfreq(a.shape[0])[:, None] / 0.5
    kx = np.fft.fftfreq(a.shape[1])[None, :] / 0.5
    r = np.sqrt(ky**2 + kx**2)
    sel = (r >= band[0]) & (r <= band[1])
    return float(np.sum(np.abs(F[sel]) ** 2) / a.size**2)


def label_thresholds(scores) -> tuple[float, float]:
    """(t_clear, t_fuzzy): label 1 at or above t_clear, 3 below t_fuzzy."""
    s = np.asarray(scores, float)
    return (float(np.quantile(s, 1 - SEED_SPLIT[0])), float(np.quantile(s, SEED_SPLIT[2])))


THRESHOLD_GRID = 41   # candidate cuts: between the scores' quantiles at 0, 1/40, ..., 1


def truth_thresholds(scores, classes) -> tuple[float, float]:
    """(t_clear, t_fuzzy) not fitted to the seed's split: of the cuts t_fuzzy <= t_clear
    midway between consecutive THRESHOLD_GRID quantiles of the scores (and beyond both
    ends), the pair whose labels (:func:`clarity_label`) equal the samples' ground-truth
    ``classes`` (1, 2, 3) most often (the first such pair in the grid's order)."""
    s = np.asarray(scores, float)
    c = np.asarray(classes, int)
    q = np.unique(np.quantile(s, np.linspace(0.0, 1.0, THRESHOLD_GRID)))
    grid = np.concatenate([[q[0] - 1.0], (q[1:] + q[:-1]) / 2, [q[-1] + 1.0]])
    best, pair = -1, (float(grid[-1]), float(grid[0]))
    for i, fuzzy in enumerate(grid):
        for clear in grid[i:]:
            labels = np.where(s >= clear, 1, np.where(s < fuzzy, 3, 2))
            hits = int((labels == c).sum())
            if hits > best:
                best, pair = hits, (float(clear), float(fuzzy))
    return pair


def clarity_label(score: float, thresholds: tuple[float, float]) -> int:
    t_clear, t_fuzzy = thresholds
    return 1 if score >= t_clear else (3 if score < t_fuzzy else 2)

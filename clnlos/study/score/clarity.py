"""Image clarity from the Fourier spectrum (seed section 3.2) and the three clarity labels.

score(img) = variance of the high-frequency band of img / max(img) (Hann-windowed, so the
             border's periodic wrap adds nothing): the image filtered to
             0.25 <= |k| / k_Nyquist <= 1 (radial), whose variance is, by Parseval,
             sum over the band of |F|^2 / N^2 (the band holds no DC, so its mean is 0).
A sharper image keeps more energy at high frequencies, and a blur (any low-pass filter)
attenuates every frequency, so the score falls monotonically as the image blurs.

Labels: 1 clear, 2 clearer (medium), 3 fuzzy, by thresholds on the score taken from the
dataset itself at the quantiles that reproduce the seed's split of 193 / 514 / 293 in 1000:
score >= q(0.807) -> 1, q(0.293) <= score < q(0.807) -> 2, score < q(0.293) -> 3.
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


def clarity_label(score: float, thresholds: tuple[float, float]) -> int:
    t_clear, t_fuzzy = thresholds
    return 1 if score >= t_clear else (3 if score < t_fuzzy else 2)

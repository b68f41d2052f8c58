"""Cross-validation by Poisson thinning: the slab SNR that best predicts held-out photons.

A photon-counting capture y (counts per bin, Poisson of mean mu) splits by binomial thinning
into two halves

    y1 ~ Binomial(y, 1/2),   y2 = y - y1,

which are *independent* Poisson of mean mu / 2 each (the thinning property of the Poisson
process; "data fission", Leiner, Duan, Wasserman & Ramdas, JASA 2023). A reconstruction made
from y1 can then be scored on y2 with no noise shared between them: for a candidate slab SNR
s, reconstruct rho_s from y1, predict the held-out half through the model, and take

    CV(s) = min_{a >= 0} || W2 y2 - a Phi2 L rho_s ||^2 / || W2 y2 ||^2,

W2 the slab's Wiener deconvolution of y2 at y2's own GCV SNR, Phi2 = W2 B its influence and
L the light-cone transport (:mod:`clnlos.inverse.iterative`); a absorbs the unknown albedo
scale. The noise of y2 is the same for every s, so CV differs between candidates only by
|| Phi2 (a L rho_s - L rho_true) ||^2 (plus a cross term with y2's noise whose spread
CV_NOISE_RUNS realisations of it estimate): the prediction error of the reconstruction where
the deconvolved data carry information. The slab SNR is searched as a factor on GCV's pick
(:func:`descend_factor`, steps of CV_STEP, within CV_FACTOR_RANGE, a step taken only where
CV falls by more than CV_SIGNIFICANCE standard errors of that cross term), the factor found
on half the photons then used on the whole capture (GCV's pick scales with the photons, the
factor with the method).

By name (``snr_rule = "thinning"``), for the iterative method on photon counts: 2-3
reconstructions of half the data on top of the one (the candidates share the halves'
preprocessing, GCV picks and deconvolutions,
:class:`clnlos.inverse.parameter_choice.PreparedCapture`). Why only deeper, what it measured and why
it is not the default: docs/validation/parameter-rules.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

THINNING_SEED = 24  # the binomial split's seed: a reconstruction is reproducible
CV_STEP = math.sqrt(10.0)  # the search's factor step (half a decade)
CV_FACTOR_RANGE = (1.0, 1e2)  # the factors on GCV's pick the search may reach: deeper only
CV_SIGNIFICANCE = 2.0  # a step must lower the score by this many standard errors
CV_FOLDS = 1  # 1: the first half predicts the second; 2: each half the other too (2x the time)
CV_NOISE_RUNS = 4  # noise realisations of the held-out half that estimate them


def thin_counts(y: np.ndarray, seed: int = THINNING_SEED) -> tuple[np.ndarray, np.ndarray]:
    """(y1, y2) with y1 ~ Binomial(y, 1/2) and y2 = y - y1 (``y`` photon counts, >= 0,
    integer valued): two independent Poisson captures of half the mean each, in y's dtype."""
    counts = np.rint(np.asarray(y, dtype=np.float64))
    if counts.size and counts.min() < 0:
        raise ValueError("thinning needs counts >= 0")
    y1 = np.random.default_rng(seed).binomial(counts.astype(np.int64), 0.5)
    return y1.astype(y.dtype), (counts - y1).astype(y.dtype)


def scaled_fit(prediction: np.ndarray, data: np.ndarray) -> np.ndarray:
    """a prediction with a = argmin_{a >= 0} ||data - a prediction||^2 (float64)."""
    p = np.asarray(prediction, dtype=np.float64)
    d = np.asarray(data, dtype=np.float64)
    pp = float(np.sum(p * p))
    return p * (max(float(np.sum(p * d)) / pp, 0.0) if pp > 0 else 0.0)


def fitted_residual(prediction: np.ndarray, data: np.ndarray, *,
                    scaled: bool = False) -> float:
    """min_{a >= 0} ||data - a prediction||^2 / ||data||^2 (dimensionless, in [0, 1]):
    the held-out error of a prediction known up to its scale (``scaled``: the prediction
    is :func:`scaled_fit`'s already)."""
    d = np.asarray(data, dtype=np.float64)
    dd = float(np.sum(d * d))
    if not dd > 0:
        return 0.0
    q = np.asarray(prediction, dtype=np.float64) if scaled else scaled_fit(prediction, d)
    return min(1.0, float(np.sum((d - q) ** 2)) / dd)


def descend_factor(score: Callable[[float], float], *, step: float = CV_STEP,
                   factor_range: tuple[float, float] = CV_FACTOR_RANGE,
                   limit: Callable[[float], bool] | None = None,
                   margin: Callable[[float, float], float] | None = None
                   ) -> tuple[float, list[tuple[float, float]]]:
    """(the factor the descent stops at, every (factor, score) tried) on a log grid
    from 1: try 1 and ``step``, then keep stepping (up, or down from 1 when ``step`` was
    worse) while the score falls, within ``factor_range`` and while ``limit(factor)`` is
    false (a factor past which nothing changes, such as a clipped SNR). With ``margin(new,
    best)``, a step is taken only where the score falls by more than that margin (a
    multiple of the difference's standard error: a move the noise could make does not
    count). Assumes the score is unimodal in log(factor), as it was on every probe; with
    the default range (1 to 100, deeper only) 2-5 evaluations."""
    lo, hi = (math.log(r) / math.log(step) for r in factor_range)
    tried: dict[float, float] = {}

    def factor(k: int) -> float:
        return 10.0 ** (k * math.log10(step))  # step ** k, exact at whole decades

    def at(k: int) -> float:
        f = factor(k)
        if f not in tried:
            tried[f] = float(score(f))
        return tried[f]

    def allowed(k: int) -> bool:
        return (lo - 1e-9 <= k <= hi + 1e-9
                and not (limit is not None and limit(factor(k))))

    best = 0
    at(best)  # first: a ``limit`` may need what scoring it records
    for direction in (1, -1):
        k = best + direction
        while allowed(k) and at(k) < at(best) - (0.0 if margin is None else
                                                 margin(factor(k), factor(best))):
            best, k = k, k + direction
        if best != 0:
            break  # the first direction improved: the other side of 1 is not tried
    return factor(best), sorted(tried.items())

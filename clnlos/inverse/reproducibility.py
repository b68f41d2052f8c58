"""Split-half reproducibility: the least regularised LCT or f-k reconstruction whose halves agree.

The counts y split by binomial thinning into two independent Poisson captures y1, y2 of half
the exposure each (:func:`clnlos.inverse.thinning.thin_counts`). Each candidate setting s =
(slab Wiener SNR, light-cone Wiener SNR) reconstructs both halves; their max-intensity
projections [y, x] are thresholded by Otsu's rule (:func:`otsu_mask`) and compared by Cohen's
kappa

    kappa = (p_o - p_e) / (1 - p_e),   p_o = P(m1 == m2),
    p_e = P(m1) P(m2) + (1 - P(m1)) (1 - P(m2)),

(dimensionless; 1: the same mask, 0: no better than two independent masks of these areas).
Candidates are tried from the least regularised down (:func:`candidate_order`: the product
of the two SNRs, at equal products the deeper slab deconvolution first); the first whose
halves agree with kappa >= :func:`kappa_min` (KAPPA_MIN with a light-cone filter, LCT;
KAPPA_MIN_SLAB_ONLY without, f-k) is used on the whole capture, else the most reproducible.
Cost: two reconstructions of half the data per candidate tried (at most 18 for LCT, 8 for
f-k), on a grid of at most REPRODUCIBILITY_SEARCH_POINTS scan points per side (a larger
capture's counts summed over blocks of scan points; the chosen SNRs then run on the capture's
own grid). How the bars, the candidate grids and the search's grid were chosen, and what
they measured: docs/validation/parameter-rules.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from clnlos.inverse.snr import CLOSED_FORM_SLAB_SNR_MIN

# the halves' masks must agree at least this much (Landis & Koch's bands): the middle of
# "substantial" where a light-cone Wiener filter follows the slab stage (LCT), its top where
# the slab filter is the only regularisation (f-k)
KAPPA_MIN = 0.7
KAPPA_MIN_SLAB_ONLY = 0.8
# the candidate SNRs (decades): the slab Wiener filter's from the decade below the GCV
# rule's floor CLOSED_FORM_SLAB_SNR_MIN (shallower ones draw reproducible artefacts) to 1e7,
# without a light-cone filter (f-k) to 1e8; the light cone's (LCT)
SLAB_SNRS = tuple(10.0 ** k for k in range(math.floor(math.log10(CLOSED_FORM_SLAB_SNR_MIN)), 8))
SLAB_SNRS_SLAB_ONLY = SLAB_SNRS + (1e8,)
LIGHTCONE_SNRS = (1e2, 1e3, 1e4)
# the halves are reconstructed on block sums of at most this many scan points per side, and
# at least REPRODUCIBILITY_SEARCH_POINTS_MIN on the shorter side (else on the capture's grid):
# a sum of Poisson counts is Poisson, and the SNR per spatial frequency both grids hold is the
# same; what the grid changes: docs/validation/parameter-rules.md, "The search's grid" (40
# points a side were tried and changed a choice)
REPRODUCIBILITY_SEARCH_POINTS = 64
REPRODUCIBILITY_SEARCH_POINTS_MIN = 48


def search_block(ny: int, nx: int) -> int:
    """Scan points per side a capture of ny x nx points is searched on the sums of: the
    fewest f dividing both sides that brings the longer within REPRODUCIBILITY_SEARCH_POINTS
    and keeps the shorter at REPRODUCIBILITY_SEARCH_POINTS_MIN or more; 1 (the capture's own
    grid) where none does."""
    lo, hi = sorted((int(ny), int(nx)))
    if hi <= REPRODUCIBILITY_SEARCH_POINTS:
        return 1
    for f in range(2, lo + 1):
        if ny % f or nx % f or hi > f * REPRODUCIBILITY_SEARCH_POINTS:
            continue
        return f if lo >= f * REPRODUCIBILITY_SEARCH_POINTS_MIN else 1
    return 1


def otsu_threshold(img: np.ndarray, bins: int = 256) -> float:
    """Threshold maximising the between-class variance of the intensity histogram (Otsu)."""
    v = np.asarray(img, np.float64).ravel()
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        return hi
    hist, edges = np.histogram(v, bins=bins, range=(lo, hi))
    p = hist / hist.sum()
    centres = (edges[:-1] + edges[1:]) / 2
    w0 = np.cumsum(p)
    m = np.cumsum(p * centres)
    mt = m[-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (mt * w0 - m) ** 2 / (w0 * (1 - w0))
    between[~np.isfinite(between)] = -1
    return float(edges[1:][int(np.argmax(between))])


def otsu_mask(volume: np.ndarray) -> np.ndarray:
    """The Otsu-thresholded max-intensity projection [y, x] of a volume [z, y, x] (bool)."""
    mip = np.asarray(volume).max(axis=0)
    return mip > otsu_threshold(mip)


def mask_agreement(a: np.ndarray, b: np.ndarray) -> float:
    """The search's score of two halves' masks: Cohen's kappa, 0 where either mask is
    constant (an empty or full mask shows nothing to agree on, however alike)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if any(m.all() or not m.any() for m in (a, b)):
        return 0.0
    return cohen_kappa(a, b)


def cohen_kappa(a: np.ndarray, b: np.ndarray) -> float:
    """Cohen's kappa of two boolean masks of one shape (module docstring); 1.0 where both
    are the same constant mask (chance agreement 1: nothing to disagree on)."""
    a, b = np.asarray(a, bool).ravel(), np.asarray(b, bool).ravel()
    if a.shape != b.shape:
        raise ValueError(f"masks of different shapes: {a.shape} and {b.shape}")
    observed = float(np.mean(a == b))
    pa, pb = float(a.mean()), float(b.mean())
    chance = pa * pb + (1 - pa) * (1 - pb)
    return 1.0 if chance >= 1.0 else (observed - chance) / (1.0 - chance)


def candidate_order(slab_snrs: Sequence[float],
                    lightcone_snrs: Sequence[float | None]) -> list[tuple[float, float | None]]:
    """The (slab SNR, light-cone SNR) candidates from the least regularised down: by the
    product of the two (a light-cone SNR of None, f-k's, counts as 1), at equal products
    the higher slab SNR first."""
    pairs = [(float(s), None if c is None else float(c)) for s in slab_snrs
             for c in lightcone_snrs]
    return sorted(pairs, key=lambda p: (p[0] * (1.0 if p[1] is None else p[1]), p[0]),
                  reverse=True)


def kappa_min(lightcone_filter: bool) -> float:
    """The agreement a method's halves must reach: KAPPA_MIN with a light-cone filter,
    KAPPA_MIN_SLAB_ONLY without one (module docstring)."""
    return KAPPA_MIN if lightcone_filter else KAPPA_MIN_SLAB_ONLY


def slab_snrs(lightcone_filter: bool) -> tuple[float, ...]:
    """The slab SNRs a method's search tries: SLAB_SNRS with a light-cone filter,
    SLAB_SNRS_SLAB_ONLY without one (module docstring)."""
    return SLAB_SNRS if lightcone_filter else SLAB_SNRS_SLAB_ONLY


def first_reproducible(candidates: Sequence[tuple[float, float | None]],
                       agreement: Callable[[tuple[float, float | None]], float],
                       bar: float
                       ) -> tuple[tuple[float, float | None], list[tuple[tuple, float]], bool]:
    """(the first candidate whose ``agreement`` (kappa of its halves) is at least ``bar``
    (the method's, :func:`kappa_min`), or the most reproducible one where none is; the
    (candidate, kappa) pairs tried, in order; whether one reached ``bar``). ``candidates``
    come least regularised first (:func:`candidate_order`)."""
    if not candidates:
        raise ValueError("no candidate settings to choose from")
    tried: list[tuple[tuple, float]] = []
    for c in candidates:
        k = float(agreement(c))
        tried.append((c, k))
        if k >= bar:
            return c, tried, True
    return max(tried, key=lambda ck: ck[1])[0], tried, False

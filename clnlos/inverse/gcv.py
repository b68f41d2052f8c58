"""The SNR of a Wiener filter chosen from the data by generalised cross-validation (numpy).

A Wiener filter conj(H) / (|H|^2 + lam) (lam = 1/SNR, H at unit DC gain) is a linear
smoother of the data y: its influence ("hat") matrix H conj(H) / (|H|^2 + lam) is diagonal in
the Fourier basis, with entries phi_k = |H_k|^2 / (|H_k|^2 + lam). Generalised
cross-validation (Golub, Heath & Wahba, Technometrics 1979; Wahba, "Spline models for
observational data", 1990, ch. 4) takes the lam that minimises

    V(lam) = (1/n) sum_k |(1 - phi_k) Y_k|^2 / [(1/n) sum_k (1 - phi_k)]^2

over the n frequencies k of the padded grid: an estimate of the predictive risk that needs
neither the noise level nor the signal spectrum. The data's own power spectrum |Y_k|^2 says,
frequency by frequency, where the blurred signal sinks into the noise, and V puts the
filter's cut-off there. Why this rule: the photon rule it replaces (SNR = photons / K_SNR,
:mod:`clnlos.inverse.snr`) assumes a flat signal spectrum, which over-states the SNR at the
frequencies the slab deconvolution lifts by up to three orders of magnitude on wide scans
(issue 24); GCV also holds for data that are not counts (measured captures rescaled by a
vendor tool, noise-free simulations where rounding is the noise), where no noise model is
known. It is asymptotically optimal for the predictive risk (Li 1986) and, unlike Stein's
unbiased risk estimate or the discrepancy principle, needs no noise variance -- which the
mirror padding, the time crop and, for the light-cone filter, the slab deconvolution
(colouring the noise) would make uncertain.

Limits. GCV assumes white noise: the light-cone filter sees noise the slab deconvolution
has coloured (blue: amplified at the frequencies the slab filter lifts), and there GCV
filters too strongly. Where the noise spectrum is known -- photon counts, whose Poisson
noise the pipeline can carry through its own linear steps -- :meth:`GcvBins.upre_snr`
(the unbiased predictive risk estimate with that spectrum) replaces it. On noise-free data
the residual is model and rounding error, not noise; the pipeline then keeps the caps
(:attr:`clnlos.inverse.snr.NoiseEstimate.noise_free`). GCV minimises a risk of the filtered data,
not of a thresholded image: the SNR best for the IoU of a method can differ (the table of
:mod:`clnlos.bench.oracle` says by how much).

V depends on the data only through the sum of |Y_k|^2 over frequencies of equal |H_k|^2:
:class:`GcvBins` groups the frequencies of one filter into bins of log10 |H|^2
(BINS_PER_DECADE), once per plan, so each capture costs one FFT and one bincount; the SNRs
tried are a log grid of TRIALS_PER_DECADE per decade.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clnlos.physics.grid import row_blocks

BINS_PER_DECADE = 32   # frequency bins per decade of |H|^2 (V's error: < 4% of a bin's lam)
TRIALS_PER_DECADE = 16  # SNRs tried per decade
GAIN_FLOOR = 1e-30     # |H|^2 below this counts as this (one bin for the dead frequencies)


def half_spectrum_weights(n_last: int, n_half: int) -> np.ndarray:
    """Multiplicity of each column of a real-to-half spectrum along its last axis (length
    ``n_half`` of a full length ``n_last``): 2 for the columns that stand for a conjugate
    pair, 1 for the zero frequency and (even ``n_last``) the Nyquist one."""
    w = np.full(n_half, 2.0)
    w[0] = 1.0
    if n_last % 2 == 0:
        w[-1] = 1.0
    return w


def fold_multiplicity(n_folded: int, n: int) -> np.ndarray:
    """How many of the n frequencies along an axis each of its ``n_folded`` = n // 2 + 1
    folded ones stands for (f and n - f): 1 for f = 0 and (even n) f = n / 2, else 2."""
    f = np.arange(n_folded)
    return np.where((f == 0) | (2 * f == n), 1.0, 2.0)


@dataclass(frozen=True)
class GcvBins:
    """The frequencies of one filter grouped by |H|^2: ``index`` (bin of each frequency of
    the half spectrum (n0, n1, n2h), uint16; for a filter whose spectrum is stored folded,
    :func:`clnlos.operators.spectral.folded_shape`, the bins of its folded quarter only,
    ``shape`` then the half spectrum's: a quarter of the memory, 21 MB in place of 85 MB
    for the 128 x 128 x 512 slab grid), ``n_last`` (the full length of the last axis: the
    half spectrum's column multiplicities, :func:`half_spectrum_weights`), ``count``
    (frequencies per bin, with their multiplicity) and ``gain`` (mean |H|^2 per bin). Built
    and used block by block of rows (:func:`clnlos.physics.grid.row_blocks`): no temporary
    of the spectrum's size."""

    index: np.ndarray
    n_last: int
    count: np.ndarray
    gain: np.ndarray
    shape: tuple[int, int, int] | None = None  # the half spectrum's, for a folded index

    @property
    def spectrum_shape(self) -> tuple[int, int, int]:
        """The half spectrum's shape (n0, n1, n2h): the grid of the powers binned."""
        return tuple(self.index.shape) if self.shape is None else self.shape

    def rows(self, r0: int, r1: int) -> np.ndarray:
        """The bins of the half spectrum's rows r0:r1 (unfolded from a folded index:
        w -> min(w, n0 - w), ky -> min(ky, n1 - ky))."""
        if self.shape is None:
            return self.index[r0:r1]
        n0, n1 = self.shape[:2]
        w = np.arange(r0, r1)
        ky = np.arange(n1)
        return self.index[np.minimum(w, n0 - w)][:, np.minimum(ky, n1 - ky)]

    @classmethod
    def from_gain(cls, gain_squared: np.ndarray, n_last: int) -> GcvBins:
        """Bins of ``gain_squared`` (|H|^2 on a half spectrum whose last axis has full
        length ``n_last``, H at unit DC gain)."""
        g = np.asarray(gain_squared)
        return cls.from_blocks(lambda r0, r1: g[r0:r1], g.shape, n_last)

    @classmethod
    def from_blocks(cls, gain_rows, shape, n_last: int, *, folded: bool = False) -> GcvBins:
        """Bins of |H|^2 given by ``gain_rows(r0, r1)`` (its rows r0:r1 of a half spectrum
        of ``shape``, float64; with ``folded``, the rows of its folded quarter,
        :func:`clnlos.operators.spectral.folded_shape`, each standing for its mirror
        frequencies too) without the whole of it in memory, each row read once: the bin of
        a gain is floor(-log10 |H|^2 BINS_PER_DECADE), numbered from the largest gain's
        after the one pass (bins no frequency falls in dropped)."""
        full = tuple(int(v) for v in shape)
        stored = (full[0] // 2 + 1, full[1] // 2 + 1, full[2]) if folded else full
        blocks = row_blocks(stored)
        # -log10 |H|^2 * BINS_PER_DECADE lies in [-2^15, 2^15) for gains above 1e-1024:
        # int16 raw bins, shifted to be >= 0 for the counts
        shift = 1 << 15
        raw = np.empty(stored, np.int16)
        w = half_spectrum_weights(n_last, full[-1])
        if folded:  # the multiplicity of each folded (w, ky) too
            w = w[None, :] * fold_multiplicity(stored[1], full[1])[:, None]
            m_rows = fold_multiplicity(stored[0], full[0])
        count = np.zeros(2 * shift)
        total = np.zeros(2 * shift)
        for r0, r1 in blocks:
            g = np.maximum(np.asarray(gain_rows(r0, r1), np.float64), GAIN_FLOOR)
            b = np.floor(-np.log10(g) * BINS_PER_DECADE)
            raw[r0:r1] = b
            idx = b.astype(np.int64).ravel() + shift
            wr = w if not folded else w[None] * m_rows[r0:r1, None, None]
            wb = np.broadcast_to(wr, g.shape).ravel()
            count += np.bincount(idx, weights=wb, minlength=2 * shift)
            total += np.bincount(idx, weights=wb * g.ravel(), minlength=2 * shift)
        used = count > 0
        keep = np.flatnonzero(used)  # bins in use, renumbered from 0 (largest gain first)
        renumber = (np.cumsum(used) - 1).astype(np.uint16)  # at most 2^16 raw bins
        index = raw.view(np.uint16)  # renumbered in place, block by block
        for r0, r1 in blocks:
            index[r0:r1] = renumber[raw[r0:r1].astype(np.int32) + shift]
        return cls(index, int(n_last), count[keep], total[keep] / count[keep],
                   full if folded else None)

    def power_per_bin(self, power: np.ndarray) -> np.ndarray:
        """Sum of the data's |Y|^2 (same half-spectrum grid) in each bin."""
        p = np.asarray(power)
        acc = BinnedPower(self)
        for r0, r1 in row_blocks(p.shape):
            acc.add(r0, p[r0:r1])
        return acc.sums

    def snr_of(self, sums: np.ndarray, snr_min: float, snr_max: float) -> float:
        """:meth:`snr` from the data's power per bin (:class:`BinnedPower`)."""
        snrs = _trial_snrs(snr_min, snr_max)
        v = self._gcv_sums(sums, snrs)
        if not np.isfinite(v).any() or not np.any(v > 0):
            return float(snr_max)
        return float(snrs[int(np.argmin(v))])

    def upre_snr_of(self, sums: np.ndarray, noise_sums: np.ndarray, snr_min: float,
                    snr_max: float) -> float:
        """:meth:`upre_snr` from the power per bin of the data and of the noise."""
        snrs = _trial_snrs(snr_min, snr_max)
        u = self._upre_sums(sums, noise_sums, snrs)
        if not np.isfinite(u).any():
            return float(snr_max)
        return float(snrs[int(np.argmin(u))])

    def gcv(self, power: np.ndarray, snrs: np.ndarray) -> np.ndarray:
        """V(1/SNR) of the module docstring for each SNR in ``snrs`` (n factors dropped)."""
        return self._gcv_sums(self.power_per_bin(power), snrs)

    def _gcv_sums(self, s: np.ndarray, snrs: np.ndarray) -> np.ndarray:
        lam = 1.0 / np.asarray(snrs, np.float64)[:, None]
        keep = 1.0 - self.gain[None, :] / (self.gain[None, :] + lam)  # 1 - phi per bin
        rss = (keep * keep * s[None, :]).sum(axis=1)
        trace = (keep * self.count[None, :]).sum(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            v = rss / (trace * trace)
        return np.where(trace > 0, v, np.inf)

    def upre(self, power: np.ndarray, noise_power: np.ndarray, snrs: np.ndarray
             ) -> np.ndarray:
        """U(1/SNR) of :func:`upre_snr`'s criterion for each SNR in ``snrs``: the data of
        power spectrum ``power`` hold noise of (expected) power spectrum ``noise_power``."""
        return self._upre_sums(self.power_per_bin(power), self.power_per_bin(noise_power),
                               snrs)

    def _upre_sums(self, s: np.ndarray, nb: np.ndarray, snrs: np.ndarray) -> np.ndarray:
        lam = 1.0 / np.asarray(snrs, np.float64)[:, None]
        phi = self.gain[None, :] / (self.gain[None, :] + lam)
        return ((1.0 - phi) ** 2 * s[None, :]).sum(axis=1) + 2.0 * (phi * nb[None, :]).sum(1)

    def upre_snr(self, power: np.ndarray, noise_power: np.ndarray, snr_min: float,
                 snr_max: float) -> float:
        """The SNR in [snr_min, snr_max] that minimises the unbiased predictive risk
        estimate (Mallows' C_L; Vogel, "Computational methods for inverse problems", 2002,
        sec. 7.1) of a filter whose data hold coloured noise of known power spectrum N_k:

            U(lam) = sum_k (1 - phi_k)^2 |Y_k|^2 + 2 sum_k phi_k N_k   (- sum_k N_k),

        an unbiased estimate of sum_k E|phi_k Y_k - S_k|^2 (S the noise-free data) for any
        noise spectrum, where GCV (:meth:`snr`) assumes N_k flat. ``noise_power``: |N_k|^2
        of one noise realisation (its sum over a bin of many frequencies is close to the
        expected one)."""
        return self.upre_snr_of(self.power_per_bin(power), self.power_per_bin(noise_power),
                                snr_min, snr_max)

    def snr(self, power: np.ndarray, snr_min: float, snr_max: float) -> float:
        """The SNR in [snr_min, snr_max] that minimises V for data of power spectrum
        ``power`` (the upper end when the data hold no power: nothing to regularise)."""
        return self.snr_of(self.power_per_bin(power), snr_min, snr_max)


def _trial_snrs(snr_min: float, snr_max: float) -> np.ndarray:
    """The log grid of SNRs tried, TRIALS_PER_DECADE per decade."""
    decades = np.log10(snr_max / snr_min)
    n = max(2, int(np.ceil(decades * TRIALS_PER_DECADE)) + 1)
    return np.logspace(np.log10(snr_min), np.log10(snr_max), n)


def row_counts(bins: GcvBins) -> np.ndarray:
    """(rows of the half spectrum, bins): the frequencies of each row in each bin, with their
    multiplicity (:func:`half_spectrum_weights`): the power per bin of a power spectrum
    constant along each row (a function of the first frequency alone) of row values s is
    ``s @ row_counts(bins)``, no pass over the spectrum."""
    n_bins = bins.count.size
    shape = bins.spectrum_shape
    w = half_spectrum_weights(bins.n_last, shape[-1])
    out = np.zeros((shape[0], n_bins))
    for r0, r1 in row_blocks(shape):
        idx = bins.rows(r0, r1).astype(np.int64)
        idx += (np.arange(r1 - r0) * n_bins)[:, None, None]
        out[r0:r1] = np.bincount(idx.ravel(), weights=np.broadcast_to(w, idx.shape).ravel(),
                                 minlength=(r1 - r0) * n_bins).reshape(r1 - r0, n_bins)
    return out


def binned_power(bins: GcvBins, blocks) -> np.ndarray:
    """The power per bin of ``bins`` from ``blocks``, an iterable of (r0, |Y|^2 of rows
    r0:r0 + len) (:meth:`clnlos.operators.spectral.SpectralFilter.power_blocks`)."""
    acc = BinnedPower(bins)
    for r0, p in blocks:
        acc.add(r0, p)
    return acc.sums


class BinnedPower:
    """The power per bin of :class:`GcvBins`, accumulated block by block of rows:
    ``add(r0, power_rows)`` for the rows r0:r0 + len of |Y|^2, then ``sums``."""

    def __init__(self, bins: GcvBins):
        self.bins = bins
        self.sums = np.zeros(bins.count.size)
        n2h = bins.index.shape[-1]
        # the columns standing for one frequency each (weight 1; the rest stand for two)
        self.single = [0] + ([n2h - 1] if bins.n_last % 2 == 0 and n2h > 1 else [])

    def add(self, r0: int, power_rows: np.ndarray) -> None:
        p = np.asarray(power_rows)
        idx = self.bins.rows(r0, r0 + p.shape[0])
        n = self.sums.size
        self.sums += 2.0 * np.bincount(idx.ravel(), weights=p.ravel(), minlength=n)
        for c in self.single:
            self.sums -= np.bincount(idx[..., c].ravel(), weights=p[..., c].ravel(),
                                     minlength=n)

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

from dataclasses import dataclass

import numpy as np

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


@dataclass(frozen=True)
class GcvBins:
    """The frequencies of one filter grouped by |H|^2: ``index`` (bin of each frequency of
    the half spectrum, flattened), ``count`` (frequencies per bin, with their half-spectrum
    multiplicity) and ``gain`` (mean |H|^2 per bin)."""

    index: np.ndarray
    weight: np.ndarray
    count: np.ndarray
    gain: np.ndarray

    @classmethod
    def from_gain(cls, gain_squared: np.ndarray, n_last: int) -> GcvBins:
        """Bins of ``gain_squared`` (|H|^2 on a half spectrum whose last axis has full
        length ``n_last``, H at unit DC gain)."""
        g = np.maximum(np.asarray(gain_squared, np.float64), GAIN_FLOOR)
        w = np.broadcast_to(half_spectrum_weights(n_last, g.shape[-1]), g.shape).ravel()
        idx = np.floor(-np.log10(g.ravel()) * BINS_PER_DECADE).astype(np.int64)
        idx -= idx.min()
        n = int(idx.max()) + 1
        count = np.bincount(idx, weights=w, minlength=n)
        mean_gain = np.bincount(idx, weights=w * g.ravel(), minlength=n)
        keep = count > 0
        mean_gain[keep] /= count[keep]
        return cls(idx.astype(np.int32), w.astype(np.float32), count, mean_gain)

    def power_per_bin(self, power: np.ndarray) -> np.ndarray:
        """Sum of the data's |Y|^2 (same half-spectrum grid) in each bin."""
        p = np.asarray(power).ravel()
        return np.bincount(self.index, weights=(self.weight * p).astype(np.float64),
                           minlength=self.count.size)

    def gcv(self, power: np.ndarray, snrs: np.ndarray) -> np.ndarray:
        """V(1/SNR) of the module docstring for each SNR in ``snrs`` (n factors dropped)."""
        s = self.power_per_bin(power)
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
        s = self.power_per_bin(power)
        nb = self.power_per_bin(noise_power)
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
        decades = np.log10(snr_max / snr_min)
        n = max(2, int(np.ceil(decades * TRIALS_PER_DECADE)) + 1)
        snrs = np.logspace(np.log10(snr_min), np.log10(snr_max), n)
        u = self.upre(power, noise_power, snrs)
        if not np.isfinite(u).any():
            return float(snr_max)
        return float(snrs[int(np.argmin(u))])

    def snr(self, power: np.ndarray, snr_min: float, snr_max: float) -> float:
        """The SNR in [snr_min, snr_max] that minimises V for data of power spectrum
        ``power`` (the upper end when the data hold no power: nothing to regularise)."""
        decades = np.log10(snr_max / snr_min)
        n = max(2, int(np.ceil(decades * TRIALS_PER_DECADE)) + 1)
        snrs = np.logspace(np.log10(snr_min), np.log10(snr_max), n)
        v = self.gcv(power, snrs)
        if not np.isfinite(v).any() or not np.any(v > 0):
            return float(snr_max)
        return float(snrs[int(np.argmin(v))])

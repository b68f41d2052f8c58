"""Noise level of a capture, and the photon rule of regularisation (pure numpy, no OpenCL).

The "auto" SNRs of a reconstruction are chosen from the data by generalised
cross-validation (:mod:`clnlos.inverse.gcv`); the photon rule below stands in for noise-free data
(:attr:`NoiseEstimate.noise_free`, where it gives the caps) and is what "today" means in
:mod:`clnlos.bench.oracle`. It assumes a flat signal spectrum, which over-states the SNR at
the frequencies the slab deconvolution lifts (by 10^2-10^3 on wide scans, issue 24).

A capture of photon counts (every value an integer) is Poisson: a bin holding n counts has
variance n. For white noise of per-bin variance s^2 over M bins the DFT has E|N(k)|^2 = M s^2,
while the signal's DC term is (sum y)^2; with Poisson s^2 = sum(y) / M their ratio at DC is
the number of photons, N = sum(y). The slab's Wiener filter conj(H) / (|H|^2 + 1/SNR), with H
at unit DC gain, therefore takes

    SNR = clip(N_signal / K_SNR, SNR_MIN, SNR_MAX)

where N_signal is the count above the background (dark counts and ambient light, the level of
the leading bins that no light from the hidden side reaches yet), K_SNR accounts for the
signal spectrum falling below its DC level at the frequencies that matter (measured on
simulated captures, see the closing note of the iterative-reconstruction issue), and
SNR_MAX is the float32 limit (and the point where light lost past the scan border makes a
deeper deconvolution inconsistent). For data that are not counts (a noise-free simulation,
data rescaled by a vendor tool), the per-bin noise is estimated from the median absolute
deviation of the second time difference, and N is replaced by the equivalent photon number
(sum y)^2 / (M s^2).

Model error. For a capture simulated by clnlos with the slab used to reconstruct it, the
slab model is exact and the photon count alone sets the SNR. A measured capture departs from
the diffusion model (detector jitter and timing, slab inhomogeneity, calibration): the error
is treated as a second noise source, SNR = 1 / (1/SNR_photons + 1/SNR_model), with
SNR_model = MEASURED_MODEL_SNR = 1e4 -- the value of the published CDT reconstructions, and
the level our sweeps on the shared CDT captures confirm (1e4 and 3e4 legible, 1e5 noisy,
the photon count's 1.5e6 unreadable).

Resampling error. A capture whose time axis was resampled -- rebinned to other bins
(``bins``, ``max_path_m``: :func:`clnlos.inverse.preprocessing.preprocess_matrix`) or its columns
moved by fractions of a bin (a reader aligning y-tal's first and last bounces or an f-k
tofgrid) -- is no longer exactly the slab blur of anything on its grid: rebinning does not
commute with the blur (a sub-bin arrival time is lost in the bin), and a fractional shift
that differs between scan points does not commute with the blur's lateral spread. That
error e = R H - H R of a unit arrival has a spectrum |E|^2 (relative to the DC power of the
blurred arrival, |H(0)|^2 = 1), and the deconvolution cannot tell it from noise: like the
photon rule, which turns a noise level into the SNR of white noise of that power,
:func:`represented_snr` takes the white noise of the error's mean power, SNR = 1 / mean
|E|^2. It is combined with the model's accuracy like a second model error
(:func:`combined_accuracy`), so that the depth does not depend on the bins a capture was
resampled to.

Background. Dark counts and ambient light add a constant floor per bin and scan point,
measured on the leading recorded bins (bins zeroed before them, a removed direct reflection,
are skipped; where the recorded window's median is lower it is taken: a window that starts
with a direct reflection the user kept). Photon counts are reconstructed less that floor
(:func:`background_subtracted`): a radiometric weighting (t/T)^p would otherwise turn it into
a ramp that the inversion puts at the far end of the volume (the diffuse S of the LCT release:
front-view NCC with the published pipeline 0.80 -> 0.96; its outdoor S in sunlight 0.87 ->
0.97). The noise statistics stay those of the raw counts.

Last light. A hidden point at depth z returns light at paths 2r >= 2z only (r >= z at every
scan point), so where no bin of photon counts after t_last rises above the background by
ARRIVAL_SIGMAS standard deviations, nothing lies deeper than c t_last / 2
(:attr:`NoiseEstimate.farthest_depth_m`): LCT's voxels there hold only the noise of the late
bins, which its radiometric weighting (t/T)^p lifts most (:class:`clnlos.inverse.lct.LCTMethod`
zeroes them). The threshold is the noise's alone, not a fraction of the peak as for the first
arrival: a direct reflection the user kept would otherwise hide faint late light. Data that
are not counts have no such test (a noise-free simulation's late bins are exact).

The light-cone Wiener filter of LCT (and of the iterative method's LCT warm start) acts on the
deconvolved transient, whose noise the first filter has shaped: it takes
sqrt(SNR), at most LIGHTCONE_SNR_MAX (:func:`lightcone_snr`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clnlos.physics.constants import C0
from clnlos.physics.grid import BLOCK_VALUES

K_SNR = 100.0
MEASURED_MODEL_SNR = 1e4  # accuracy of the slab model on measured captures (see docstring)
SNR_MIN = 1e2
SNR_MAX = 1e10
LIGHTCONE_SNR_MAX = 1e4
LIGHTCONE_RULE = "upre"  # light-cone SNR of photon counts: "upre" (noise known) or "gcv"
LIGHTCONE_SNR_MIN = 10.0  # lower end of the light-cone SNRs cross-validation tries
# the least slab SNR, where it is chosen from the data, of a method that takes the deconvolved
# transient for the slab-free one (Inversion.slab_snr_min; :mod:`clnlos.inverse.pipeline`)
CLOSED_FORM_SLAB_SNR_MIN = 3e5
LEAD_FRACTION = 0.05  # the first 5% of the recorded window estimates the background
ARRIVAL_SIGMAS = 6.0  # a bin holds signal when above background by this many std
ARRIVAL_FRACTION = 1e-3  # ... and by this fraction of the peak of the scan-summed profile


@dataclass(frozen=True)
class NoiseEstimate:
    """Noise statistics of one capture [t, y, x] and the rules derived from them."""

    photon_counts: bool         # integer data: Poisson statistics
    total: float                # sum over the capture
    background_per_bin: float   # mean level per bin and scan point before any signal
    signal: float               # total minus the background
    sigma: float                # per-bin noise std (Poisson: sqrt of the mean level)
    equivalent_photons: float   # N of the module docstring
    snr: float                  # Wiener SNR of the slab deconvolution
    first_arrival_s: float | None  # earliest bin start with signal (s), None if none found
    last_arrival_s: float | None = None  # photon counts: end of the last bin with light (s)

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @property
    def noise_free(self) -> bool:
        """No noise measurable: data that are not counts whose noise estimate puts the
        photon rule's SNR at its cap SNR_MAX (a simulation without a detector).
        Cross-validation (:mod:`clnlos.inverse.gcv`) has then no noise to weigh the fit
        against: the caps apply. Photon counts are never noise-free, however many: their
        Poisson noise is known and cross-validation still finds where it stops the
        deconvolution (the wide 'UT' at 1.3e12 photons: GCV's slab SNR 2.1e7, LCT IoU 0.82,
        where the cap 1e10 that the photon rule reaches there gave 0.27)."""
        return not self.photon_counts and self.snr >= SNR_MAX

    @property
    def nearest_depth_m(self) -> float | None:
        """Depth bound c t / 2 of the first arrival: no hidden point is nearer (r >= z)."""
        return None if self.first_arrival_s is None else C0 * self.first_arrival_s / 2

    @property
    def farthest_depth_m(self) -> float | None:
        """Depth bound c t / 2 of the last arrival: no hidden point is farther (its light
        would arrive later, r >= z); None where not measured (data that are not counts, no
        light found)."""
        return None if self.last_arrival_s is None else C0 * self.last_arrival_s / 2


def combined_snr(photon_snr: float, model_snr: float) -> float:
    """1 / (1/photon + 1/model), clipped to [SNR_MIN, SNR_MAX] (model_snr may be inf: the
    photon SNR as it is)."""
    if math.isinf(model_snr):
        return float(np.clip(photon_snr, SNR_MIN, SNR_MAX))
    return float(np.clip(1.0 / (1.0 / photon_snr + 1.0 / model_snr), SNR_MIN, SNR_MAX))


def lightcone_snr(snr: float) -> float:
    """SNR of the light-cone Wiener filter after a slab deconvolution of SNR ``snr``."""
    return float(min(math.sqrt(snr), LIGHTCONE_SNR_MAX))


def is_counts(y: np.ndarray) -> bool:
    """Every value a non-negative integer (photon counts), and not all zero."""
    a = np.asarray(y)
    if a.size == 0 or not np.any(a):
        return False
    if np.issubdtype(a.dtype, np.integer):
        return True
    flat = a.reshape(-1)
    probe = flat[:: max(1, flat.size // 4096)]  # fast rejection of non-count data
    if not np.array_equal(probe, np.rint(probe)):
        return False
    for s in range(0, flat.size, BLOCK_VALUES):  # block by block: no capture-sized temporary
        b = flat[s:s + BLOCK_VALUES]
        if not (np.array_equal(b, np.rint(b)) and b.min() >= 0):
            return False
    return True


def _mad_sigma(y: np.ndarray) -> float:
    """Per-bin white-noise std from the second time difference (robust to smooth signal):
    var(y[t+1] - 2 y[t] + y[t-1]) = 6 s^2 for white noise. ``y`` [t, columns], any float
    dtype: the differences are taken in float64 block by block of columns into one array,
    whose medians are taken in place (the median of a set does not depend on its order):
    one float64 array of the capture's size, no further copies."""
    nt, n = y.shape
    if nt < 3:
        return 0.0
    d2 = np.empty((nt - 2, n))
    step = max(1, BLOCK_VALUES // nt)
    for c0 in range(0, n, step):
        b = np.asarray(y[:, c0:c0 + step], np.float64)
        d2[:, c0:c0 + step] = b[2:] - 2 * b[1:-1] + b[:-2]
    d2 -= np.median(d2, overwrite_input=True)
    np.abs(d2, out=d2)
    mad = float(np.median(d2, overwrite_input=True))
    return 1.4826 * mad / math.sqrt(6.0)


def estimate_noise(y: np.ndarray, bin_width_s: float, start_s: float = 0.0) -> NoiseEstimate:
    """Noise statistics of a capture ``y`` [t, y, x] with bins of ``bin_width_s`` from
    ``start_s`` (see module docstring)."""
    a = np.asarray(y)
    if not np.issubdtype(a.dtype, np.floating):
        a = a.astype(np.float64)
    nt = a.shape[0]
    n_scan = int(np.prod(a.shape[1:])) or 1
    counts = is_counts(a)
    profile = a.reshape(nt, -1).sum(axis=1, dtype=np.float64)
    k0 = first_recorded_bin(profile)
    lead = max(1, int(round(LEAD_FRACTION * (nt - k0))))
    # the floor: the leading recorded bins, or the recorded window's median where that is
    # lower (a window that starts at a direct reflection kept by the user)
    background = min(float(np.median(profile[k0:k0 + lead])),
                     float(np.median(profile[k0:]))) / n_scan
    total = float(profile.sum())
    signal = max(0.0, total - background * n_scan * (nt - k0))  # the floor where recorded
    if counts:
        sigma = math.sqrt(max(total / a.size, 1e-300))
        n_eq = signal
        prof_std = math.sqrt(max(background * n_scan, 1.0))
    else:
        sigma = _mad_sigma(a.reshape(nt, -1))
        n_eq = math.inf if sigma == 0 else total * total / (a.size * sigma * sigma)
        prof_std = sigma * math.sqrt(n_scan)
    snr = float(np.clip(n_eq / K_SNR, SNR_MIN, SNR_MAX)) if n_eq > 0 else SNR_MIN
    excess = profile - background * n_scan
    thresh = max(ARRIVAL_SIGMAS * prof_std, ARRIVAL_FRACTION * float(excess.max(initial=0.0)))
    hits = np.nonzero(excess > thresh)[0]
    first = float(start_s + hits[0] * bin_width_s) if hits.size and excess.max() > 0 else None
    return NoiseEstimate(counts, total, background, signal, sigma, n_eq, snr, first,
                         last_arrival(excess, prof_std, bin_width_s, start_s)
                         if counts and first is not None else None)


def last_arrival(excess: np.ndarray, profile_std: float, bin_width_s: float,
                 start_s: float) -> float | None:
    """End (s) of the last bin of the scan-summed ``excess`` over the background that rises
    above it by ARRIVAL_SIGMAS times ``profile_std`` (the noise's std per bin of the
    profile), None where none does (module docstring, "Last light")."""
    hits = np.nonzero(excess > ARRIVAL_SIGMAS * profile_std)[0]
    return float(start_s + (hits[-1] + 1) * bin_width_s) if hits.size else None


def first_recorded_bin(profile: np.ndarray) -> int:
    """The first bin of a scan-summed ``profile`` that is not zero: the bins before it were
    not recorded or were zeroed (a direct reflection cut,
    :func:`clnlos.io.capture.without_direct`), so the background is measured after it."""
    nz = np.flatnonzero(np.asarray(profile))
    return int(nz[0]) if nz.size else 0


def background_subtracted(y: np.ndarray, noise: NoiseEstimate, dtype=np.float32
                          ) -> np.ndarray:
    """Photon counts ``y`` [t, y, x] less their background (dark counts and ambient light,
    ``noise.background_per_bin`` per bin and scan point) from the first recorded bin on: a
    constant floor that a radiometric weighting (t/T)^p would turn into a ramp toward the
    end of the window. Other data, counts without a background or without a bin above it
    (``noise.first_arrival_s`` None), are returned as given (in ``dtype``)."""
    a = np.asarray(y)
    b = noise.background_per_bin
    if not (noise.photon_counts and b > 0 and noise.first_arrival_s is not None):
        return np.asarray(a, dtype)  # no light found above the floor: nothing to take it from
    out = np.array(a, dtype=dtype, copy=True)
    k0 = first_recorded_bin(out.reshape(out.shape[0], -1).sum(axis=1, dtype=np.float64))
    out[k0:] -= b
    return out


def combined_accuracy(*snrs: float) -> float:
    """Independent model errors given as SNRs combined: 1 / sum(1 / snr) (inf: no error)."""
    inv = sum(0.0 if math.isinf(s) else 1.0 / s for s in snrs)
    return math.inf if inv == 0 else 1.0 / inv


def represented_snr(error_sq: np.ndarray) -> float:
    """The slab SNR a resampled model supports: 1 / the mean of ``error_sq``, the spectrum
    |E|^2 of the resampling error of a unit arrival relative to the blur's DC power (the
    SNR of white noise of the error's power; module docstring); inf without an error."""
    m = float(np.mean(np.asarray(error_sq, np.float64))) if np.size(error_sq) else 0.0
    return math.inf if not m > 0 else 1.0 / m


def rebinning_error(matrix, kernel_in: np.ndarray, kernel_out: np.ndarray,
                    probes: int = 512) -> np.ndarray:
    """|E|^2 of a time-axis resampling ``matrix`` (rows: output bins, columns: input bins;
    scipy sparse) against the slab blur's energy per lag on the input grid (``kernel_in``)
    and on the output grid (``kernel_out``), on the output grid padded to twice its length
    (the deconvolution's): the mean over ``probes`` consecutive input bins m (every phase
    of m against the output bins) of |F[A (h_in * delta_m) - h_out * (A delta_m)]|^2 over
    the mean |F[A delta_m]|^2, h_out normalised to unit DC."""
    a = matrix.tocsc()
    rows, cols = a.shape
    h_in = np.asarray(kernel_in, np.float64)
    h_out = np.asarray(kernel_out, np.float64)
    used = np.nonzero(np.diff(a.indptr))[0]
    n_fft = 2 * rows
    gain = np.fft.rfft(h_out, n_fft)
    dc = gain[0].real if gain.size else 0.0
    if not used.size or not dc > 0:
        return np.zeros(n_fft // 2 + 1)
    m = np.arange(used[0], min(cols, used[0] + probes))
    lag = np.arange(cols)[:, None] - m[None, :]
    shifted = np.where((lag >= 0) & (lag < h_in.size), h_in[np.clip(lag, 0, h_in.size - 1)],
                       0.0)
    truth = a @ shifted                                   # A (h_in * delta_m)
    moved = a[:, m].toarray()                             # A delta_m
    model = np.fft.irfft(np.fft.rfft(moved, n_fft, axis=0) * gain[:, None], n_fft,
                         axis=0)[:rows]                   # h_out * (A delta_m)
    err = np.abs(np.fft.rfft(truth - model, n_fft, axis=0)) ** 2
    sig = np.abs(np.fft.rfft(moved, n_fft, axis=0)) ** 2
    return err.mean(axis=1) / max(float(sig.mean()), 1e-300) / (dc * dc)


def column_shift_error(psf_t_spectrum: np.ndarray, fractions: np.ndarray,
                       bin_fraction: float, probes: int = 4) -> np.ndarray:
    """|E|^2 on the padded grid [w, ky, kx] of shifting each column of a [t, y, x] capture
    by its own fraction of a bin (``fractions`` [y, x], in bins of ``bin_fraction`` times
    the blur grid's bin), a 2-tap interpolation K_p(w) = 1 + f_p (exp(-i w dt) - 1).

    ``psf_t_spectrum`` [w, Y, X]: the blur at unit DC gain, transformed along t only (the
    padded lateral grid in wrap order). For an arrival at scan point p0 the error
    K H delta - H K delta is, at lateral offset D, (f_{p0+D} - f_p0)(exp(-i w dt) - 1)
    H(w, D); it is transformed laterally and |.|^2 averaged over a probes x probes lattice
    of scan points p0."""
    h = np.asarray(psf_t_spectrum)
    nw, py, px = h.shape
    f = np.asarray(fractions, np.float64)
    ny, nx = f.shape
    w = np.pi * np.arange(nw) / max(nw - 1, 1) * float(bin_fraction)  # w dt, rad
    step = np.abs(np.exp(-1j * w) - 1.0) ** 2
    out = np.zeros(h.shape)
    lattice = [(int((i + 0.5) * ny / probes), int((j + 0.5) * nx / probes))
               for i in range(min(probes, ny)) for j in range(min(probes, nx))]
    for y0, x0 in lattice:
        d = np.zeros((py, px))
        dy = (np.arange(ny) - y0) % py
        dx = (np.arange(nx) - x0) % px
        d[np.ix_(dy, dx)] = f - f[y0, x0]
        out += np.abs(np.fft.fft2(h * d[None], axes=(1, 2))) ** 2
    return out * step[:, None, None] / len(lattice)

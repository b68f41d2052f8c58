"""Capture -> the pipeline's grid: the one resampling of the time axis (align to t = 0, crop
to the kept path, rebin; guard bins for the slab deconvolution), the geometry a capture and
a config resolve to, the slab to deconvolve, what a window cut costs a deconvolution, and
the device bytes a pipeline needs before a capture is read (:mod:`clnlos.inverse.pipeline`
runs them)."""

from __future__ import annotations

import math

import numpy as np

from clnlos.config import ReconstructionConfig, check_window
from clnlos.errors import InputFileError, MissingParameterError, ParameterError
from clnlos.inverse.snr import ARRIVAL_SIGMAS, first_recorded_bin, is_counts
from clnlos.io.capture import Capture
from clnlos.operators.resample import overlap_matrix
from clnlos.physics.constants import C0


def preprocess_matrix(nt_in: int, bin_width_s: float, start_s: float, max_path_m: float | None,
                      bins: int | None, guard_fraction: float = 0.0):
    """(matrix, new bin width, n_out): align to t = 0, crop to max path, rebin -- one resampling.

    The matrix has ``n_out + n_guard`` rows: up to ``guard_fraction * n_out`` extra bins past
    the kept window, taken from the capture where it extends that far. The slab
    deconvolution runs on them (light that entered the window late leaves the slab after
    it), then they are dropped, so the deconvolution's edge effects fall outside the volume.
    """
    src_edges = start_s + bin_width_s * np.arange(nt_in + 1)
    n_keep, n_out = preprocess_bins(nt_in, bin_width_s, start_s, max_path_m, bins)
    t_keep = n_keep * bin_width_s
    dt_out = t_keep / n_out
    n_avail = int(np.floor((src_edges[-1] - t_keep) / dt_out + 1e-9))
    n_guard = max(0, min(n_avail, int(np.ceil(guard_fraction * n_out))))
    dst_edges = np.linspace(0.0, t_keep + n_guard * dt_out, n_out + n_guard + 1)
    return overlap_matrix(src_edges, dst_edges), dt_out, n_out


MIN_DEPTH_BINS = 2  # a volume with fewer depth bins has no depth to resolve (a note says so)
GUARD_PEAKS = 2.0  # a cut is harmless behind this many blur peak lags of guard bins (the
#                   deconvolved bins past the volume): the inverse filter's ringing stays there


def cut_level(snr: float) -> float:
    """The light still arriving at a window's end (fraction of the peak) above which the cut
    matters to a Wiener deconvolution of SNR ``snr``: 1 / sqrt(snr), the amplitude the
    filter itself treats as noise (1e-2 at SNR 1e4; 1e-5 for a noise-free capture at the
    SNR cap, whose inverse filter turns even a 0.3% step into the brightest voxels)."""
    return 1.0 / math.sqrt(snr)


def window_end_level(profile: np.ndarray, *, background: float, end_bins: int,
                     photon_counts: bool, sigma: float, n_scan: int) -> float:
    """How much light still arrives at the end of the time window: the mean of the scan-summed
    transient ``profile`` over its last ``end_bins`` bins above ``background`` (per bin of
    the profile), as a fraction of its peak above the background; 0 where that excess is
    within ARRIVAL_SIGMAS standard deviations of the mean's noise (Poisson for counts,
    ``sigma`` per bin and scan point otherwise)."""
    m = max(1, min(int(end_bins), profile.size))
    excess = float(profile[-m:].mean()) - background
    top = float(profile.max()) - background
    if not top > 0:
        return 0.0
    std = (math.sqrt(max(float(profile[-m:].mean()), 1.0) / m) if photon_counts
           else sigma * math.sqrt(n_scan / m))
    return max(0.0, excess / top) if excess > ARRIVAL_SIGMAS * std else 0.0


def preprocess_bins(nt_in: int, bin_width_s: float, start_s: float,
                    max_path_m: float | None, bins: int | None) -> tuple[int, int]:
    """(capture bins kept from t = 0, bins after rebinning) of :func:`preprocess_matrix`,
    from the capture's time axis alone."""
    t_end = start_s + bin_width_s * nt_in
    if max_path_m is not None:
        t_end = min(t_end, max_path_m / C0)
    if t_end <= 0:
        raise ParameterError("preprocess.max_path_m", max_path_m,
                             "a path length that keeps some of the capture's time window")
    n_keep = max(1, int(round(t_end / bin_width_s)))
    return n_keep, n_keep if bins is None else int(bins)


def bins_for(config: ReconstructionConfig, nt_in: int, bin_width_s: float,
             start_s: float) -> int | None:
    """The bins the preprocessing rebins to: the config's ``bins`` (None: all of them; a
    method that sums a long capture's noise-only band, :func:`bandwidth_bins`, has set
    ``bins`` before the pipeline is built)."""
    return config.bins


BAND_COLUMNS = 1024  # scan columns per block of the band test's FFT along t (bounded memory)


def band_excess(transient: np.ndarray, rows: tuple[int, int], bin_width_s: float,
                band_hz: tuple[float, float]) -> float:
    """How far the photon counts ``transient`` [t, y, x] rise above their Poisson noise in a
    frequency band along t, in standard deviations: over the rows ``rows`` = (r0, r1), the
    column power spectrum |F_t[y - mean]|^2 summed over the band (lo, hi] (Hz) and over the
    columns, less the Poisson floor (the counts of each column, for every frequency), over
    the floor's standard deviation (sqrt(bins x columns) times the mean floor: each
    frequency's power of white Poisson noise is exponential about it)."""
    r0, r1 = rows
    y = np.asarray(transient)[r0:r1].reshape(r1 - r0, -1)
    f = np.fft.rfftfreq(r1 - r0, bin_width_s)
    band = (f > band_hz[0]) & (f <= band_hz[1])
    if not band.any() or y.shape[1] == 0:
        return 0.0
    power = floor = 0.0
    for c0 in range(0, y.shape[1], BAND_COLUMNS):
        blk = y[:, c0:c0 + BAND_COLUMNS].astype(np.float64)
        spec = np.fft.rfft(blk - blk.mean(axis=0), axis=0)[band]
        power += float(np.sum(spec.real ** 2 + spec.imag ** 2))
        floor += float(blk.sum()) * int(band.sum())
    sd = floor / math.sqrt(int(band.sum()) * y.shape[1])
    return (power - floor) / sd if sd > 0 else 0.0


def bandwidth_bins(transient: np.ndarray, *, bins_kept: int, bin_width_s: float,
                   start_s: float, above: int) -> tuple[int | None, str | None]:
    """(bins, one note line) for a capture of photon counts whose kept window (``bins_kept``
    bins of ``bin_width_s`` from t = 0; the capture's axis starts at ``start_s``) holds more
    than ``above`` bins: halved (bins summed in pairs) while the band each halving removes,
    (1/(4 dt), 1/(2 dt)] for bins of dt, rises above the counts' Poisson noise by less than
    ARRIVAL_SIGMAS standard deviations (:func:`band_excess`, over the recorded bins of the
    window): the sum loses only noise there. (None, None) where nothing is summed: data that
    are not counts (no noise to tell signal from: a noise-free render keeps every bin), or
    a band that holds signal."""
    if above is None or bins_kept <= above or not is_counts(transient):
        return None, None
    y = np.asarray(transient)
    k0 = max(0, int(math.floor(-start_s / bin_width_s)))
    k1 = min(y.shape[0], k0 + bins_kept)
    profile = y[k0:k1].reshape(k1 - k0, -1).sum(axis=1, dtype=np.float64)
    r0 = k0 + first_recorded_bin(profile)
    n, excess = bins_kept, None
    while n > above:
        dt = bins_kept * bin_width_s / n
        e = band_excess(y, (r0, k1), bin_width_s, (1 / (4 * dt), 1 / (2 * dt)))
        if e > ARRIVAL_SIGMAS:
            break
        n, excess = n // 2, e
    if n == bins_kept:
        return None, None
    dt = bins_kept * bin_width_s / n
    return n, (f"{n} bins of {dt * 1e12:.3g} ps (the {bins_kept} of "
               f"{bin_width_s * 1e12:.3g} ps summed in groups of {bins_kept // n}): the "
               f"capture's counts hold no signal above {1e-9 / (2 * dt):.3g} GHz (the band "
               f"summed away is at their Poisson noise, {excess:+.1f} sd), and the iterative "
               f"method's cost is per bin (--bins {bins_kept} / bins={bins_kept} keeps them)")


def device_bytes_needed(shape_in, *, bin_width_s: float, start_s: float,
                        config: ReconstructionConfig, dtype=np.float32) -> tuple[int, int]:
    """(device bytes in all, bytes of the largest buffer) that a pipeline for captures of
    ``shape_in`` [t, y, x] allocates at least: the capture, and twice (the filter's and
    the work buffer) the half spectrum of the inversion's padded grid (2 n, 2 ny, 2 nx),
    n the bins after preprocessing. Lower bounds, from the declared sizes alone: a check
    before a capture is read (:func:`clnlos.runtime.limits.capture_use`) never refuses one that
    fits."""
    nt_in, ny, nx = (int(v) for v in shape_in)
    _, n = preprocess_bins(nt_in, bin_width_s, start_s, config.max_path_m,
                           bins_for(config, nt_in, bin_width_s, start_s))
    item = np.dtype(dtype).itemsize
    spectrum = 2 * n * 2 * ny * (nx + 1) * 2 * item  # (2n, 2ny, 2nx) real -> half, complex
    return nt_in * ny * nx * item + 2 * spectrum, spectrum


def setup_slab(config: ReconstructionConfig, capture: Capture
               ) -> tuple[ReconstructionConfig, str]:
    """For a config without a slab: the slab the capture recorded (a clnlos simulation), with
    a one-line note of what was chosen."""
    recorded = capture.recorded_slab()
    if recorded is None:
        return config, ("no slab given (--slab-* flags or [slab]) or recorded in the capture: "
                        "no deconvolution runs (plain NLOS)")
    slab, nd = recorded
    cfg = config.replace(slab=slab, n_dipoles=config.n_dipoles if nd is None else nd)
    return cfg, f"using the slab recorded in the capture: {describe_slab(slab)} (--no-slab " \
                "to skip the deconvolution)"


def describe_slab(slab) -> str:
    return (f"d = {slab.thickness_m:g} m, mu_a = {slab.mu_a:g} 1/m, mu_s' = "
            f"{slab.mu_s_prime:g} 1/m, n = {slab.n:g}")


def resolve_geometry(capture: Capture, config: ReconstructionConfig, *,
                     names: dict[str, str] | None = None) -> tuple[float, float, float]:
    """(bin_width_s, start_s, scan_width_m): the config overrides the file; the time window
    is checked (:func:`clnlos.config.check_window`, errors naming ``names`` or the TOML
    fields)."""
    src = capture.source or "the capture"
    bw = config.bin_width_s if config.bin_width_s is not None else capture.bin_width_s
    if bw is None:
        raise MissingParameterError("--bin-width", f"{src} does not store its bin width; "
                                    "give --bin-width (s) or [capture] bin_width_s")
    sw = config.scan_width_m if config.scan_width_m is not None else capture.scan_width_m
    if sw is None:
        why = capture.attrs.get("scan_width_unknown", f"{src} does not store the scan width")
        raise MissingParameterError("--scan-width", f"{why}; give --scan-width (the side "
                                    "along x, m) or [capture] scan_width_m")
    ny, nx = capture.transient.shape[1:]
    if config.scan_width_m is None and capture.scan_height_m is not None and not math.isclose(
            capture.scan_height_m / ny, sw / nx, rel_tol=1e-6):
        raise InputFileError(f"{capture.source or 'the capture'}: a scan pitch of "
                             f"{sw / nx:.4g} m along x and {capture.scan_height_m / ny:.4g} m "
                             "along y: clnlos reconstructs scans of square cells only")
    start = config.start_s if config.start_s is not None else capture.start_s
    check_window(capture.transient.shape[0], float(bw), float(start), config, names=names,
                 source=capture.source or "the capture")
    return float(bw), float(start), float(sw)


def centred_extents(extents: dict, center) -> dict:
    """The volume's lateral extents moved to a scan grid centred at ``center`` (x, y) m."""
    cx, cy = (float(v) for v in center)
    out = dict(extents)
    for key, shift in (("x_min_m", cx), ("x_max_m", cx), ("y_min_m", cy), ("y_max_m", cy)):
        out[key] = extents[key] + shift
    return out


def aligned_window_note(capture: Capture) -> str | None:
    """One line where a reader cut the window to the bins every scan point recorded after
    moving the columns to align them (:func:`clnlos.io.formats.common.align_columns`)."""
    recorded = capture.attrs.get("aligned_from_bins")
    shifts = capture.time_shift_bins
    kept = capture.transient.shape[0]
    if shifts is None or recorded is None or kept >= recorded:
        return None
    bw = capture.bin_width_s or 0.0
    return (f"the columns were moved {np.min(shifts):.4g}-{np.max(shifts):.4g} bins earlier "
            f"to align the scan points: the window is cut to the {kept} bins "
            f"({kept * bw * 1e9:.3g} ns) every scan point recorded, of {recorded}")

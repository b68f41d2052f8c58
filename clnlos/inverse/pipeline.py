"""Reconstruction pipeline: capture -> preprocess -> [slab deconvolution] -> confocal inverse.

Stages (each a plan built once for the capture's shape, dtype and device):

1. ``preprocess``: one mass-conserving resampling of the time axis that aligns bin 0 to
   t = 0 (using ``start_s``), crops to ``max_path_m`` of round-trip path and rebins to
   ``bins`` bins (sums of overlapping bins, never point samples); then normalisation.
2. ``deconvolve`` (only with a slab): Wiener deconvolution of Phi * Phi
   (:mod:`clnlos.forward.blur`), W = conj(H) / (|H|^2 + 1/SNR), H at unit DC gain.
3. ``invert``: a registered method (:mod:`clnlos.inverse.methods`): LCT
   (:mod:`clnlos.inverse.lct`), f-k migration (:mod:`clnlos.inverse.fk`) or the regularised
   iterative inversion (:mod:`clnlos.inverse.iterative`).

SNRs given as "auto" are chosen from the data, each on its own filter's grid
(:mod:`clnlos.inverse.gcv`): the slab's by generalised cross-validation on the preprocessed
transient (for LCT and f-k at least ``Inversion.slab_snr_min``, f-k toward the photon
rule's, :func:`method_slab_snr`), combined with the slab model's accuracy
(:func:`model_snr_for`: exact for a capture simulated with this slab, else
MEASURED_MODEL_SNR) as 1/SNR = 1/SNR_data + 1/SNR_model; the light cone's on the
deconvolved transient by the unbiased predictive risk estimate with the capture's own noise
carried through the same steps (photon counts), else by GCV. On photon counts the slab model
fits exactly a split search may choose them instead (:mod:`clnlos.inverse.reproducibility`
for LCT and f-k, :mod:`clnlos.inverse.thinning` for the iterative method by name); a
:class:`PreparedCapture` shares what the candidates of a search do not change. Which rule
runs on which capture, and how each was chosen: docs/parameters.md and
docs/validation/parameter-rules.md.

Output volume [z, y, x]: depth bin k spans [k, k+1) * c * dt / 2 behind the scan plane
(the slab's hidden face), x and y the scan-cell centres, x increasing with the column
index and y with the row index (images are drawn with +x to the right and +y up), the
extents centred where the capture's scan grid is (``Capture.scan_center_m``).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field

import numpy as np
import pyopencl.array as cla

from clnlos.physics.constants import C0
from clnlos.brdf.lobes import AUTO, auto_challengers, auto_ladder
from clnlos.config import ReconstructionConfig, check_window
from clnlos.errors import InputFileError, MissingParameterError, ParameterError
from clnlos.forward.blur import blur_time_scales, confocal_lag_energy, confocal_psf, slab_blur
from clnlos.inverse.brdf_choice import (
    LOBE_NOT_SEARCHED,
    LOBE_NOT_SEARCHED_REASON,
    LOBE_SEARCH_ITERATIONS,
    challenge,
    choose_lobe,
    score_margin,
)
from clnlos.inverse.capture_defaults import format_defaults
from clnlos.inverse.gcv import GcvBins, binned_power
from clnlos.inverse.methods import METHODS, InversionGrid, method_class
from clnlos.inverse.reproducibility import (
    LIGHTCONE_SNRS,
    candidate_order,
    first_reproducible,
    kappa_min,
    mask_agreement,
    otsu_mask,
    slab_snrs,
)
from clnlos.inverse.snr import (
    ARRIVAL_SIGMAS,
    LEAD_FRACTION,
    background_subtracted,
    MEASURED_MODEL_SNR,
    SNR_MAX,
    SNR_MIN,
    NoiseEstimate,
    column_shift_error,
    combined_accuracy,
    combined_snr,
    estimate_noise,
    is_counts,
    lightcone_snr,
    rebinning_error,
    represented_snr,
)
from clnlos.inverse.tail_fill import TailFilledDeconvolution
from clnlos.inverse.thinning import (
    CV_FACTOR_RANGE,
    CV_FOLDS,
    CV_NOISE_RUNS,
    CV_SIGNIFICANCE,
    CV_STEP,
    descend_factor,
    fitted_residual,
    scaled_fit,
    thin_counts,
)
from clnlos.io.capture import Capture, without_direct
from clnlos.operators.resample import AxisResample, overlap_matrix
from clnlos.physics.grid import row_blocks
from clnlos.physics.lobe import RetroLobe
from clnlos.runtime.buffers import Scratch, host_view, round_up
from clnlos.runtime.caches import PIPELINES
from clnlos.runtime.device import get_queue, has_fp64, require_dtype
from clnlos.runtime.programs import get_kernels, real_defines
from clnlos.runtime.spectrum_cache import SpectrumCache


@dataclass
class Reconstruction:
    """What a reconstruction returns: ``volume`` [z, y, x] float (albedo, a.u.), the time and
    scan geometry it used (``bin_width_s`` s, ``scan_width_m`` m), the ``stages`` that ran
    and their ``timings_s`` (s), ``params`` (every parameter, with the SNRs used and the rules
    that chose them: ``snr_used``, ``snr_rule_used``, ``inversion_snr_used``, ...), the
    preprocessed ``transient`` when kept, ``extents`` (``depth_min_m``, ``depth_max_m``,
    ``voxel_depth_m``, ``x_min_m`` ... ``y_max_m``, ``voxel_lateral_m``: m), ``noise`` (the
    capture's noise estimate), ``solver`` (the iterative solver's report) and ``notes`` (one
    line each, for the user)."""

    volume: np.ndarray
    bin_width_s: float
    scan_width_m: float
    stages: list[str]
    timings_s: dict[str, float]
    params: dict
    transient: np.ndarray | None = None
    extents: dict = field(default_factory=dict)
    noise: dict = field(default_factory=dict)      # clnlos.inverse.snr.NoiseEstimate of the capture
    solver: dict | None = None                     # iterative: the solver's report
    notes: list[str] = field(default_factory=list)  # one line each, for the user


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


INFLUENCE_ENERGY_TOL = 1e-5  # the slab influence's kernel keeps all but this of its energy
NOISE_PROBE_SEED = 0     # the noise realisation of ReconstructionPipeline._noise_like


class NoiseProbe:
    """A realisation of the inverted transient's noise, computed on the first call (the
    methods that need it: :mod:`clnlos.inverse.methods`)."""

    def __init__(self, make):
        self.make, self.value = make, None

    def __call__(self):
        if self.value is None:
            self.value = self.make()
        return self.value

DECONVOLVED_KEPT = 4  # slab SNRs whose deconvolution a prepared capture keeps (a search's)


@dataclass
class PreparedCapture:
    """A capture preprocessed once for every reconstruction made of it (the candidates of a
    split search: :meth:`ReconstructionPipeline.reproducibility_snrs`,
    :meth:`ReconstructionPipeline.thinning_factor`): the raw counts and their noise
    estimate, the preprocessed and normalised transient ``tau`` (device, guard bins kept;
    never changed), its scan-summed profile and the normalisation ``scale``; filled in as
    the candidates need them: the slab GCV pick, the deconvolutions by slab SNR (the last
    DECONVOLVED_KEPT, with what each added to a volume's params and notes), the tail fills
    of the data and of the noise realisation (:class:`TailFilledDeconvolution` memos), and
    the noise realisation preprocessed (:meth:`ReconstructionPipeline._probe`)."""

    transient: np.ndarray
    noise: NoiseEstimate
    tau: cla.Array
    profile: np.ndarray
    scale: float
    gcv_snr: float | None = None
    deconvolved: dict = field(default_factory=dict)
    fills: dict = field(default_factory=dict)
    noise_fills: dict = field(default_factory=dict)
    noise_tau: cla.Array | None = None

    def keep(self, snr: float, entry: tuple) -> tuple:
        """Keep the deconvolution at ``snr`` (the oldest dropped past DECONVOLVED_KEPT)."""
        self.deconvolved[snr] = entry
        while len(self.deconvolved) > DECONVOLVED_KEPT:
            self.deconvolved.pop(next(iter(self.deconvolved)))
        return entry


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
    """The bins the preprocessing rebins to: the config's ``bins``, else for a method with a
    ``max_bins`` (:class:`clnlos.inverse.methods.MethodEntry`) the kept bins halved (summed in
    pairs) until at most that many, else None (all of them)."""
    cap = METHODS[config.method].max_bins if config.method in METHODS else None
    if config.bins is not None or cap is None:
        return config.bins
    n_keep, _ = preprocess_bins(nt_in, bin_width_s, start_s, config.max_path_m, None)
    n = n_keep
    while n > cap:
        n = (n + 1) // 2
    return None if n == n_keep else n


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


def model_snr_for(capture: Capture, config: ReconstructionConfig) -> float:
    """The slab model's accuracy as an SNR (:mod:`clnlos.inverse.snr`): the configured number, or
    for "auto" infinite when the capture was simulated by clnlos with this very slab (the
    model made the data) and MEASURED_MODEL_SNR otherwise."""
    if config.model_snr != "auto":
        return float(config.model_snr)
    if config.slab is None:  # no deconvolution: the recorded slab is not read (--no-slab)
        return math.inf
    recorded = capture.recorded_slab()
    if recorded is not None and recorded[0] == config.slab:
        return math.inf
    return MEASURED_MODEL_SNR


def method_slab_snr(gcv_snr: float, slab_snr_min: float | None,
                    photon_snr: float | None = None) -> float:
    """The data's slab SNR for a method: cross-validation's ``gcv_snr``; where
    ``photon_snr`` (the photon rule's, :mod:`clnlos.inverse.snr`) is given and higher, the
    geometric mean sqrt(gcv_snr photon_snr); at least the method's ``slab_snr_min`` where it
    has one (:attr:`clnlos.inverse.methods.Inversion.slab_snr_min`). Before the model's
    accuracy is combined with it (:func:`auto_snrs`, which also clips to SNR_MAX)."""
    snr = gcv_snr
    if photon_snr is not None and photon_snr > gcv_snr:
        snr = math.sqrt(gcv_snr * photon_snr)
    return snr if slab_snr_min is None else max(snr, float(slab_snr_min))


def auto_snrs(noise: NoiseEstimate, config: ReconstructionConfig,
              model_snr: float = math.inf, *, data_snr: float | None = None,
              data_inversion_snr: float | None = None) -> tuple[float, float]:
    """(deconvolution SNR, light-cone SNR) of a capture: the configured numbers, or for
    "auto" the data's own (``data_snr`` for the slab, combined with ``model_snr``;
    ``data_inversion_snr`` for the light cone: :mod:`clnlos.inverse.gcv`) where given, else the
    photon rule of :mod:`clnlos.inverse.snr` (photon count and model accuracy;
    :func:`lightcone_snr`)."""
    if config.snr != "auto":
        snr = float(config.snr)
    else:
        snr = combined_snr(noise.snr if data_snr is None else data_snr, model_snr)
    if config.inversion_snr != "auto":
        inv = float(config.inversion_snr)
    else:
        inv = lightcone_snr(snr) if data_inversion_snr is None else float(data_inversion_snr)
    return snr, inv


# what a split search records where a half of the split holds no counts (the GCV rule kept)
SPLIT_EMPTY_REASON = "a half of the split holds no counts"
SPLIT_EMPTY = f"gcv ({SPLIT_EMPTY_REASON})"


class ReconstructionPipeline:
    """The composed stages for one capture geometry (shape, bin width, scan width);
    ``setup(step)`` names each step of the construction as it starts."""

    # the factors on GCV's slab SNR the thinning search may reach (clnlos.inverse.thinning;
    # a measurement may widen it: tools/snr_rule_check.py --both-ways)
    thinning_factor_range = CV_FACTOR_RANGE

    def __init__(self, shape_in, *, bin_width_s: float, start_s: float, scan_width_m: float,
                 config: ReconstructionConfig, dtype=np.float32, queue=None, setup=None):
        setup = setup or (lambda step: None)
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.config = config
        nt_in, ny, nx = shape_in
        guard = config.guard_fraction if config.slab is not None else 0.0
        A, self.bin_width_s, n_out = preprocess_matrix(
            nt_in, bin_width_s, start_s, config.max_path_m,
            bins_for(config, nt_in, bin_width_s, start_s), guard)
        self.scan_width_m = scan_width_m
        self.shape = (n_out, ny, nx)
        self.n_guard = A.shape[0] - n_out
        # the raw bins inside the kept window [0, n_out * dt): the noise is estimated on them
        # (resampling would turn counts into non-integers and change their statistics)
        self.raw_bin_width_s, self.raw_start_s = float(bin_width_s), float(start_s)
        t_keep = n_out * self.bin_width_s
        self.raw_window = (max(0, int(np.floor(-start_s / bin_width_s))),
                           min(nt_in, int(np.ceil((t_keep - start_s) / bin_width_s))))
        self.stages = ["preprocess"]
        setup("preprocess")
        self.pre = AxisResample(A, (ny, nx), dtype=self.dtype, queue=self.queue)
        self.pre.name = "preprocess"
        self._pre_matrix = A
        self._rebin_snr: float | None = None  # what the rebinned model represents, on first use
        self._rk = get_kernels(self.queue, "resample", real_defines(self.dtype))
        pitch = scan_width_m / nx
        snr0 = 1.0 if config.snr == "auto" else float(config.snr)  # set per capture if auto
        self.deconv = None
        self._gcv_slab: GcvBins | None = None  # the slab filter's GCV bins, on first use
        self.scratch = Scratch(self.queue)  # work buffers shared by the stages below
        cache = SpectrumCache.from_settings()  # CLNLOS_SPECTRUM_CACHE: spectra kept on disk
        if config.slab is not None:
            setup("slab PSF")
            self.deconv = slab_blur(config.slab, (A.shape[0], ny, nx),
                                    bin_width_s=self.bin_width_s, pitch_m=pitch, mode="wiener",
                                    snr=snr0, n_dipoles=config.n_dipoles,
                                    lateral_pad=config.lateral_pad, dtype=self.dtype,
                                    queue=self.queue, scratch=self.scratch, cache=cache)
            self.stages.append(f"deconvolve:slab({describe_slab(config.slab)})")
            self.blur_scales = blur_time_scales(config.slab, bin_width_s=self.bin_width_s,
                                                queue=self.queue)
            self._deconv_args = dict(bin_width_s=self.bin_width_s, pitch_m=pitch,
                                     n_dipoles=config.n_dipoles, scales=self.blur_scales,
                                     lateral_pad=config.lateral_pad, dtype=self.dtype,
                                     queue=self.queue, scratch=self.scratch, cache=cache)
            self._tail_deconv = None
        setup(f"{config.method} plan")
        self.invert = method_class(config.method)(
            InversionGrid(self.shape, self.bin_width_s, scan_width_m), config, dtype=self.dtype,
            queue=self.queue, scratch=self.scratch, cache=cache)
        self.stages.append(f"invert:{config.method}")

    def resampling_snr(self, time_shifts: np.ndarray | None = None) -> float:
        """The deepest slab SNR the model represents after the time axis was resampled
        (:func:`clnlos.inverse.snr.represented_snr`; inf when it was not, or without a
        slab): by the preprocessing (rebinned, or moved by a fraction of a bin), and by a
        reader that moved each column by its own ``time_shifts`` [y, x] (raw bins; their
        fractional parts interpolate)."""
        if self.deconv is None:
            return math.inf
        if self._rebin_snr is None:
            self._rebin_snr = self._rebinned_model_snr()
        shifted = math.inf
        if time_shifts is not None:
            frac = np.asarray(time_shifts, np.float64) % 1.0
            if np.ptp(frac) > 0:
                shifted = self._shifted_model_snr(frac)
        return combined_accuracy(self._rebin_snr, shifted)

    def _rebinned_model_snr(self) -> float:
        """:func:`resampling_snr` of the preprocessing alone: inf where it only selects
        whole bins, else the rebinning error of the slab blur's energy per lag
        (:func:`clnlos.inverse.snr.rebinning_error`)."""
        a = self._pre_matrix.tocsr()
        if np.all(np.diff(a.indptr) <= 1) and np.all(a.data == 1.0):
            return math.inf
        slab, nd = self.config.slab, self.config.n_dipoles
        h_in = confocal_lag_energy(slab, nt=a.shape[1], bin_width_s=self.raw_bin_width_s,
                                   n_dipoles=nd, queue=self.queue)
        h_out = confocal_lag_energy(slab, nt=a.shape[0], bin_width_s=self.bin_width_s,
                                    n_dipoles=nd, queue=self.queue)
        return represented_snr(rebinning_error(a, h_in, h_out))

    def _shifted_model_snr(self, fractions: np.ndarray) -> float:
        """:func:`resampling_snr` of columns moved by their own ``fractions`` of a raw bin
        (:func:`clnlos.inverse.snr.column_shift_error`), on the deconvolution's grid."""
        rows, ny, nx = self._pre_matrix.shape[0], self.shape[1], self.shape[2]
        dt = np.float64 if has_fp64(self.queue.device) else np.float32
        psf = confocal_psf(self.config.slab, (rows, ny, nx), bin_width_s=self.bin_width_s,
                           pitch_m=self.scan_width_m / nx, n_dipoles=self.config.n_dipoles,
                           dtype=dt, queue=self.queue).get()
        psf_t = np.fft.rfft(psf / psf.sum(dtype=np.float64), axis=0)
        return represented_snr(column_shift_error(psf_t, fractions,
                                                  self.raw_bin_width_s / self.bin_width_s))

    def slab_gcv_snr(self, tau: cla.Array) -> float:
        """The slab Wiener SNR in [SNR_MIN, SNR_MAX] that generalised cross-validation
        (:mod:`clnlos.inverse.gcv`) picks for the preprocessed transient ``tau`` (device, guard
        bins included): V on the deconvolution's padded grid, padded as it pads."""
        if self._gcv_slab is None:
            self._gcv_slab = GcvBins.from_blocks(self.deconv.gain_rows,
                                                 self.deconv.fft.spec_shape,
                                                 self.deconv.pad_shape[2])
        bins = self._gcv_slab
        sums = binned_power(bins, self.deconv.power_blocks(row_blocks(bins.index.shape), tau))
        return bins.snr_of(sums, SNR_MIN, SNR_MAX)

    def _timed(self, timings, name, fn, *a, **kw):
        self.queue.finish()
        t0 = time.perf_counter()
        out = fn(*a, **kw)
        self.queue.finish()
        timings[name] = timings.get(name, 0.0) + time.perf_counter() - t0
        return out

    def run(self, transient: np.ndarray, *, keep_transient: bool = False,
            progress=None, model_snr: float = math.inf, setup=None,
            slab_snr_factor: float | None = None,
            snrs: tuple[float, float | None] | None = None,
            time_shifts: np.ndarray | None = None,
            lobe: RetroLobe | None = None) -> Reconstruction:
        """Reconstruct one capture. ``progress(k, n)`` is called during the iterative
        method's iterations, ``setup(step)`` as each of its set-up steps before them starts;
        ``model_snr`` is the slab model's accuracy (:func:`model_snr_for`);
        ``slab_snr_factor`` multiplies GCV's slab SNR in place of the method's rule (the
        thinning search's candidates, :meth:`thinning_factor`); ``snrs`` = (slab SNR,
        light-cone SNR or None: the config's) replaces an "auto" slab SNR (as given, the
        model's accuracy not combined) and the light-cone rule (the reproducibility
        search's candidates, :meth:`reproducibility_snrs`); ``time_shifts``: the shifts a
        reader moved the columns by (:attr:`clnlos.io.capture.Capture.time_shift_bins`).
        An "auto" slab SNR is bounded by what the resampled model represents
        (:meth:`resampling_snr`); ``lobe`` replaces the retro lobe ``brdf = "auto"``
        would choose (the lobe search's candidates, :meth:`brdf_lobe`)."""
        timings: dict[str, float] = {}
        noise = self.raw_noise(transient)
        resampled = self.resampling_snr(time_shifts)
        cv: dict | None = None
        lobe_params: dict = {}
        if self.config.brdf == AUTO:
            if lobe is None:
                t0 = time.perf_counter()
                lobe, lobe_params = self.brdf_lobe(transient, noise, model_snr, setup)
                timings["choose_brdf"] = time.perf_counter() - t0
            self.invert.set_lobe(lobe)
        if slab_snr_factor is None and self._thinning_applies(transient, noise, model_snr):
            t0 = time.perf_counter()
            slab_snr_factor, cv = self.thinning_factor(transient, model_snr, setup,
                                                       resampled=resampled)
            timings["choose_snr_thinning"] = time.perf_counter() - t0
        if (snrs is None and slab_snr_factor is None
                and self._reproducibility_applies(transient, noise, model_snr)):
            t0 = time.perf_counter()
            snrs, cv = self.reproducibility_snrs(transient, model_snr, setup,
                                                 resampled=resampled)
            timings["choose_snr_reproducibility"] = time.perf_counter() - t0
        prep = self.prepare(transient, noise, timings)
        return self._reconstruct(prep, timings, keep_transient=keep_transient,
                                 progress=progress, model_snr=model_snr, setup=setup,
                                 slab_snr_factor=slab_snr_factor, snrs=snrs, cv=cv,
                                 resampled=resampled, time_shifts=time_shifts,
                                 lobe_params=lobe_params)

    def prepare(self, transient: np.ndarray, noise: NoiseEstimate | None = None,
                timings: dict | None = None) -> PreparedCapture:
        """The capture preprocessed and normalised once (:class:`PreparedCapture`), for
        :meth:`_reconstruct` (every candidate of a split search reuses it)."""
        noise = self.raw_noise(transient) if noise is None else noise
        x = cla.to_device(self.queue, np.ascontiguousarray(
            background_subtracted(transient, noise, self.dtype)))
        tau = self._timed({} if timings is None else timings, "preprocess", self.pre, x)
        profile, peak = self._profile_peak(tau)
        total = float(profile.sum())
        if not peak > 0:
            raise InputFileError("the capture holds no signal in the kept time window "
                                 "(all zero): nothing to reconstruct")
        norm = self.config.normalize
        scale = 1.0
        if norm != "none":
            s = peak if norm == "max" else total
            if s > 0:
                scale = 1.0 / s
                self._scale_inplace(tau, scale)
        return PreparedCapture(np.asarray(transient), noise, tau, profile, scale)

    def _reconstruct(self, prep: PreparedCapture, timings: dict, *,
                     keep_transient: bool = False, progress=None,
                     model_snr: float = math.inf, setup=None,
                     slab_snr_factor: float | None = None,
                     snrs: tuple[float, float | None] | None = None,
                     cv: dict | None = None, resampled: float = math.inf,
                     time_shifts: np.ndarray | None = None,
                     lobe_params: dict | None = None) -> Reconstruction:
        """:meth:`run` on a prepared capture, its SNR rule's search (``cv``) done: the
        deconvolutions at each slab SNR and the noise realisation through the
        preprocessing are kept in ``prep`` for the next candidate; ``resampled`` the slab
        SNR the resampled model represents (:meth:`resampling_snr`, for ``time_shifts``);
        ``lobe_params`` what the lobe search of ``brdf = "auto"`` recorded."""
        noise, tau = prep.noise, prep.tau
        data_snr = gcv_snr = None
        unbounded = model_snr
        model_snr = combined_accuracy(model_snr, resampled)
        if snrs is not None:  # a candidate of the search, as given (no model share but
            model_snr = unbounded = resampled  # what the resampling leaves representable)
            data_snr = snrs[0]
        elif self.deconv is not None and self.config.snr == "auto" and not noise.noise_free:
            if prep.gcv_snr is None:
                prep.gcv_snr = self._timed(timings, "choose_snr", self.slab_gcv_snr, tau)
            gcv_snr = prep.gcv_snr
            data_snr = method_slab_snr(gcv_snr, self.invert.slab_snr_min, noise.snr if
                                       self.invert.slab_snr_toward_photons else None)
            if slab_snr_factor is not None:
                data_snr = float(np.clip(gcv_snr * slab_snr_factor, SNR_MIN, SNR_MAX))
        snr, inv_snr = auto_snrs(noise, self.config, model_snr, data_snr=data_snr,
                                 data_inversion_snr=None if snrs is None else snrs[1])
        inv_rule = None if snrs is None or snrs[1] is None else "reproducibility"
        params = self.config.as_attrs()
        params.update(lobe_params or {})
        notes: list[str] = []
        if (lobe_params or {}).get("brdf_rule_used") == LOBE_NOT_SEARCHED:
            notes.append(f"brdf auto: {LOBE_NOT_SEARCHED_REASON}; the Lambertian lobe")
        if math.isfinite(resampled) and self.deconv is not None:
            params["resampling_snr"] = resampled
            free = auto_snrs(noise, self.config, unbounded, data_snr=data_snr)[0]
            if snrs is None and snr < free / 2:
                notes.append(self._resampling_note(snr, free, time_shifts))
        named = self.config.snr_rule
        if named in ("thinning", "reproducibility") and cv is None and (
                slab_snr_factor is None and snrs is None):
            notes.append(f"snr_rule {named} not applied (it needs an \"auto\" slab SNR, a "
                         "slab and photon counts): the GCV rule or the configured SNRs")
        if cv is not None and cv.get("snr_rule_used") == SPLIT_EMPTY:
            notes.append(f"no split search ({SPLIT_EMPTY_REASON}): the GCV rule")
        elif cv is not None and cv.get("reproducibility_agreed") is False:
            notes.append(f"no candidate's halves agreed to kappa >= "
                         f"{cv['reproducibility_kappa_min']:g}: the most "
                         f"reproducible (kappa {cv['reproducibility_kappa']:.2f}) was taken")
        deconv = None
        if self.deconv is not None:
            params["snr_used"] = snr
            if gcv_snr is not None:
                params["snr_data"] = gcv_snr  # cross-validation's, before the model's share
                inv = self.invert
                if inv.slab_snr_min is not None or inv.slab_snr_toward_photons:  # a rule
                    params["slab_snr_min"] = inv.slab_snr_min
                    params["slab_snr_raised"] = data_snr != gcv_snr  # and if it acted
            params["model_snr_used"] = model_snr
            if cv is not None:
                params.update(cv)
            elif gcv_snr is not None and slab_snr_factor is None and snrs is None:
                params["snr_rule_used"] = "gcv"  # what "auto" came to (the method's floor
                #                                  on top where it has one: slab_snr_raised)
            deconv, tau = self._deconvolved(prep, snr, params, notes, timings)
        elif self.n_guard:
            tau = tau[:self.shape[0]]  # the guard bins dropped: a view of the leading rows
        method = self.config.method
        probe = (NoiseProbe(lambda: self._probe(prep, deconv, snr))
                 if noise.photon_counts and not noise.noise_free else None)
        influence = (None if self.deconv is None else
                     lambda: self._slab_influence(snr))
        params.update(self.invert.configure(
            tau, noise, inv_snr, lambda name, fn, *a: self._timed(timings, name, fn, *a),
            probe, influence, **({} if inv_rule is None else {"rule": inv_rule})))
        vol = self._timed(timings, f"invert:{method}", self.invert, tau, progress=progress,
                          setup=setup)
        solve = self.invert.report()
        params.update(self.invert.used())
        volume = vol.get()
        if snrs is None and slab_snr_factor is None:  # the searches' own runs say nothing
            notes.extend(self.result_notes(volume, noise, params, prep.transient))
        nt, ny, nx = self.shape
        dz = C0 * self.bin_width_s / 2
        w = self.scan_width_m
        extents = {"depth_min_m": 0.0, "depth_max_m": nt * dz, "voxel_depth_m": dz,
                   "x_min_m": -w / 2, "x_max_m": w / 2, "y_min_m": -w * ny / nx / 2,
                   "y_max_m": w * ny / nx / 2, "voxel_lateral_m": w / nx}
        return Reconstruction(volume=volume, bin_width_s=self.bin_width_s, scan_width_m=w,
                              stages=list(self.stages), timings_s=timings, params=params,
                              transient=tau.get() if keep_transient else None, extents=extents,
                              noise=noise.as_dict(), solver=solve, notes=notes)

    def _deconvolved(self, prep: PreparedCapture, snr: float, params: dict, notes: list,
                     timings: dict) -> tuple:
        """(the slab deconvolution at ``snr``, the prepared transient deconvolved by it on
        the inverted grid): computed once per SNR and kept in ``prep`` with what it adds
        to the params and notes; a tail fill (:mod:`clnlos.inverse.tail_fill`) once per
        fill SNR."""
        hit = prep.deconvolved.get(snr)
        if hit is None:
            added, extra = {}, []
            deconv = self._deconvolution_for(prep.profile, prep.noise, snr, added, extra)
            deconv.set_snr(snr)
            if isinstance(deconv, TailFilledDeconvolution):
                out = self._timed(timings, "deconvolve", deconv, prep.tau, prep.fills)
                added["tail_fill_snr"] = deconv.fill_snr  # the fill's SNR (tail_fill)
                added["tail_filled_snr_applied"] = deconv.applied_snr  # its final filter's
            else:
                out = self._timed(timings, "deconvolve", deconv, prep.tau)
            if self.n_guard:
                out = out[:self.shape[0]]  # the guard bins dropped: the leading rows
            hit = prep.keep(snr, (deconv, out, added, extra))
        deconv, out, added, extra = hit
        deconv.set_snr(snr)
        params.update(added)
        notes.extend(extra)
        return deconv, out

    def raw_noise(self, transient: np.ndarray) -> NoiseEstimate:
        """The noise of the raw capture's bins inside the kept window
        (:func:`clnlos.inverse.snr.estimate_noise`)."""
        k0, k1 = self.raw_window
        return estimate_noise(np.asarray(transient)[k0:k1], self.raw_bin_width_s,
                              self.raw_start_s + k0 * self.raw_bin_width_s)

    def brdf_lobe(self, transient: np.ndarray, noise: NoiseEstimate, model_snr: float,
                  setup=None) -> tuple[RetroLobe, dict]:
        """(the retro lobe ``brdf = "auto"`` takes for this capture, the params recording the
        search): the lobe of :func:`clnlos.brdf.lobes.auto_ladder` whose reconstruction from
        one half of a binomial split of the counts best predicts the other half
        (:mod:`clnlos.inverse.brdf_choice`); the Lambertian lobe where the capture is not
        counts or a half is empty (:data:`LOBE_NOT_SEARCHED`)."""
        halves = self._split(transient) if (noise.photon_counts and not noise.noise_free
                                            and is_counts(np.asarray(transient))) else None
        if halves is None:
            return RetroLobe.lambert(), {"brdf_rule_used": LOBE_NOT_SEARCHED}
        train, test = halves
        held, phi, noise_runs = self._held_out_prediction_target(test)
        fits: dict[str, np.ndarray] = {}

        def score(cand: RetroLobe) -> float:
            if setup is not None:
                setup(f"BRDF lobe by thinning: {cand.name}")
            with self.invert.iteration_budget(LOBE_SEARCH_ITERATIONS):
                rec = self.run(train, model_snr=model_snr, slab_snr_factor=1.0, lobe=cand)
            pred = self.invert.predict(rec.volume)
            pred = (pred if phi is None else phi.apply_device(pred)).get()
            fits[cand.name] = scaled_fit(pred, held)
            return fitted_residual(fits[cand.name], held, scaled=True)

        def margin(new: RetroLobe, best: RetroLobe) -> float:
            return score_margin(fits[new.name], fits[best.name], held, noise_runs)

        chosen, tried = choose_lobe(auto_ladder(), score, margin)
        chosen, tried = challenge(chosen, tried, auto_challengers(), score, margin)
        return chosen, {"brdf_rule_used": "thinning", "brdf_chosen": chosen.name,
                        "brdf_tried": json.dumps([[c, v] for c, v in tried])}

    def _held_out_prediction_target(self, y2: np.ndarray):
        """(the held-out half as the inversion sees it, host; the slab's influence Phi2 that a
        prediction goes through, or None without a slab; realisations of its noise): with a
        slab, :meth:`_held_out` (deconvolved at its own GCV SNR); without, preprocessed and
        divided by its peak."""
        if self.deconv is not None:
            held, snr, noise_runs = self._held_out(y2)
            return held, self._slab_influence(snr), noise_runs
        tau = self.pre(cla.to_device(self.queue, np.ascontiguousarray(y2, self.dtype)))
        _, peak = self._profile_peak(tau)
        scale = 1.0 / peak if peak > 0 else 1.0
        if peak > 0:
            self._scale_inplace(tau, scale)
        noise_runs = [self._noise_like(y2, scale, None, 0.0, NOISE_PROBE_SEED + 1 + j).get()
                      for j in range(CV_NOISE_RUNS)]
        return tau.get(), None, noise_runs

    def _thinning_applies(self, transient: np.ndarray, noise: NoiseEstimate,
                          model_snr: float) -> bool:
        """Whether an "auto" slab SNR is chosen by thinning: the config's rule is thinning
        (:attr:`clnlos.config.ReconstructionConfig.thinning`), with a slab, a method with a
        forward model and a capture of photon counts (``noise``: the raw capture's,
        :meth:`raw_noise`); under ``snr_rule = "auto"`` also only where the slab model is
        exact (``model_snr`` infinite: a capture clnlos simulated with this slab). The score
        takes Phi2 L rho for the held-out photons' mean: on a measured capture the model's
        own error (MEASURED_MODEL_SNR, 1e4) exceeds the photon noise it would judge by, and
        the combined SNR is capped at it anyway."""
        return self.invert.forward_model and self._split_search_applies(
            self.config.thinning, transient, noise, model_snr)

    def _reproducibility_applies(self, transient: np.ndarray, noise: NoiseEstimate,
                                 model_snr: float) -> bool:
        """Whether "auto" SNRs are chosen by split-half reproducibility: the config's rule
        is it (:attr:`clnlos.config.ReconstructionConfig.reproducibility`: LCT and f-k under
        "auto"), with a slab, an "auto" slab SNR and a capture of photon counts; under
        ``snr_rule = "auto"`` also only where the slab model is exact (``model_snr``
        infinite). On a measured capture the model's error is the same in both halves: they
        would agree on it, and the combined SNR is capped at MEASURED_MODEL_SNR anyway."""
        return self._split_search_applies(self.config.reproducibility, transient, noise,
                                          model_snr)

    def _split_search_applies(self, rule_on: bool, transient: np.ndarray,
                              noise: NoiseEstimate, model_snr: float) -> bool:
        """The gate both split searches share: their rule on (``rule_on``), not under
        ``snr_rule = "auto"`` where the slab model is inexact (``model_snr`` finite), an
        "auto" slab SNR, a slab, and a capture of photon counts (``noise``: the raw
        capture's, :meth:`raw_noise`)."""
        c = self.config
        if not rule_on or (c.snr_rule == "auto" and math.isfinite(model_snr)):
            return False
        return (c.snr == "auto" and self.deconv is not None and noise.photon_counts
                and not noise.noise_free and is_counts(np.asarray(transient)))

    def _split(self, transient: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The binomial split of the counts (:func:`clnlos.inverse.thinning.thin_counts`),
        or None where a half holds no counts in the kept window (the searches then keep
        the GCV rule, recorded as :data:`SPLIT_EMPTY`)."""
        halves = thin_counts(np.asarray(transient))
        k0, k1 = self.raw_window
        return halves if all(np.any(h[k0:k1]) for h in halves) else None

    def reproducibility_candidates(self) -> list[tuple[float, float | None]]:
        """The (slab SNR, light-cone SNR) settings the search tries, least regularised first
        (:func:`clnlos.inverse.reproducibility.candidate_order`): the light-cone SNRs where
        the method has a light-cone filter and the config leaves its SNR to "auto"."""
        lc = (LIGHTCONE_SNRS if self.invert.lightcone_filter
              and self.config.inversion_snr == "auto" else (None,))
        return candidate_order(slab_snrs(self.invert.lightcone_filter), lc)

    def reproducibility_snrs(self, transient: np.ndarray, model_snr: float = math.inf,
                             setup=None, *, resampled: float = math.inf
                             ) -> tuple[tuple[float, float | None] | None, dict]:
        """((slab SNR, light-cone SNR or None), the params recording the search): the first
        of :meth:`reproducibility_candidates` at which the two halves of a binomial split of
        the counts (:func:`clnlos.inverse.thinning.thin_counts`) give Otsu masks of their
        max-intensity projections that agree with Cohen's kappa >= the method's bar
        (:func:`clnlos.inverse.reproducibility.kappa_min`), else the most
        reproducible candidate (:mod:`clnlos.inverse.reproducibility`; a note says so). The
        candidates are used as given: on a measured capture (``snr_rule`` by name) the
        model's accuracy is not combined with them. Where a half holds no counts in the
        window, the method's GCV rule stands (None, and a note)."""
        halves = self._split(transient)
        if halves is None:
            return None, {"snr_rule_used": SPLIT_EMPTY}
        prepared = [self.prepare(h) for h in halves]

        def agreement(cand: tuple[float, float | None]) -> float:
            if setup is not None:
                lc = "" if cand[1] is None else f", light cone {cand[1]:.3g}"
                setup(f"SNRs by reproducibility: slab {cand[0]:.3g}{lc}")
            masks = [otsu_mask(self._reconstruct(h, {}, model_snr=model_snr, snrs=cand,
                                                 resampled=resampled).volume)
                     for h in prepared]
            return mask_agreement(*masks)

        bar = kappa_min(self.invert.lightcone_filter)
        chosen, tried, agreed = first_reproducible(self.reproducibility_candidates(),
                                                   agreement, bar)
        kappa = dict(tried)[chosen]
        return chosen, {"snr_rule_used": "reproducibility", "reproducibility_kappa": kappa,
                        "reproducibility_kappa_min": bar,
                        "reproducibility_agreed": agreed,
                        "reproducibility_tried": json.dumps([[c[0], c[1], k]
                                                             for c, k in tried])}

    def thinning_factor(self, transient: np.ndarray, model_snr: float = math.inf,
                        setup=None, *, resampled: float = math.inf) -> tuple[float, dict]:
        """(factor on GCV's slab SNR, the params recording the search) by cross-validation
        on a binomial split of the counts (:mod:`clnlos.inverse.thinning`): for each
        candidate the first half is reconstructed at that factor on its own GCV pick and its
        prediction Phi2 L rho scored against the second half deconvolved at that half's own
        GCV SNR (with CV_FOLDS = 2 also the other way round, the score the folds' mean).
        Where a half holds no counts in the window, GCV's pick (factor 1) stands."""
        halves = self._split(transient)
        if halves is None:
            return 1.0, {"snr_rule_used": SPLIT_EMPTY}
        folds = []
        for train, test in list(zip(halves, halves[::-1], strict=True))[:CV_FOLDS]:
            held, snr, noise = self._held_out(test)
            folds.append((self.prepare(train), held, self._slab_influence(snr), noise,
                          float(np.sum(np.square(held, dtype=np.float64)))))
        gcv_train: list[float] = []
        fits: dict[float, list[np.ndarray]] = {}

        def score(f: float) -> float:
            if setup is not None:
                setup(f"slab SNR by thinning: {f:.3g} x GCV's pick")
            scores, fits[f] = [], []
            for train, held, phi, _, _ in folds:
                rec = self._reconstruct(train, {}, model_snr=model_snr, slab_snr_factor=f,
                                        resampled=resampled)
                gcv_train.append(rec.params.get("snr_data", math.nan))
                pred = phi.apply_device(self.invert.predict(rec.volume)).get()
                fits[f].append(scaled_fit(pred, held))
                scores.append(fitted_residual(fits[f][-1], held, scaled=True))
            return float(np.mean(scores))

        def margin(f_new: float, f_best: float) -> float:
            """CV_SIGNIFICANCE standard errors of the score difference's part from the
            held-out half's noise, 2 <n, q_new - q_best> / ||held||^2 over each fold's noise
            realisations (the folds' variances summed as if independent). The split's own
            variation (which half each photon went to) is not in it: on a 16 x 16 'UT' it
            was 3-6x larger (12 split seeds), so a choice between neighbouring factors can
            depend on THINNING_SEED (clnlos.inverse.thinning)."""
            var = 0.0
            for k, (_, _, _, noise, energy) in enumerate(folds):
                d = (fits[f_new][k] - fits[f_best][k]).ravel()
                var += np.mean([(2.0 * float(r.ravel() @ d) / energy) ** 2 for r in noise])
            return CV_SIGNIFICANCE * math.sqrt(var) / len(folds)

        def clipped(f: float) -> bool:  # the step before already at SNR_MAX: no change
            g = gcv_train[0] if gcv_train else math.nan
            return not g * f / CV_STEP < SNR_MAX

        factor, tried = descend_factor(score, limit=clipped, margin=margin,
                                       factor_range=self.thinning_factor_range)
        return factor, {"snr_rule_used": "thinning", "thinning_factor": factor,
                        "thinning_tried": json.dumps([[f, v] for f, v in tried])}

    def _held_out(self, y2: np.ndarray) -> tuple[np.ndarray, float, list[np.ndarray]]:
        """(the held-out half's deconvolved transient on the inverted grid, host; its GCV
        slab SNR; CV_NOISE_RUNS realisations of its noise through the same steps,
        :meth:`_noise_like`): preprocessed, divided by its peak (the score fits the scale)
        and deconvolved at the SNR GCV picks for it (:meth:`slab_gcv_snr`), tail-filled where
        the window needs it."""
        tau = self.pre(cla.to_device(self.queue, np.ascontiguousarray(y2, self.dtype)))
        profile, peak = self._profile_peak(tau)
        if peak > 0:
            self._scale_inplace(tau, 1.0 / peak)
        noise = self.raw_noise(y2)
        snr = self.slab_gcv_snr(tau)
        deconv = self._deconvolution_for(profile, noise, snr, {}, [])
        deconv.set_snr(snr)
        out = deconv(tau)[:self.shape[0]].get()
        scale = 1.0 / peak if peak > 0 else 1.0
        noise_runs = [self._noise_like(y2, scale, deconv, snr, NOISE_PROBE_SEED + 1 + j).get()
                      for j in range(CV_NOISE_RUNS)]
        return out, snr, noise_runs

    @staticmethod
    def _profile_peak(tau: cla.Array) -> tuple[np.ndarray, float]:
        """(the scan-summed profile [t], float64; the peak) of a preprocessed transient:
        small reductions on the host, no kernel builds."""
        with host_view(tau) as t_host:
            profile = t_host.reshape(t_host.shape[0], -1).sum(axis=1, dtype=np.float64)
            return profile, float(t_host.max())

    def _scale_inplace(self, a: cla.Array, s: float) -> None:
        """a *= s on the device (the normalisation of a transient and of its noise)."""
        self._rk.scale_inplace(self.queue, (round_up(a.size, 256),), None, a.data,
                               self.dtype.type(s), np.int64(a.size))

    def _slab_influence(self, snr: float):
        """The influence Phi of the slab's Wiener filter at ``snr`` on the inverted
        transient's grid (guard bins dropped: the rows past the volume are zero;
        :meth:`clnlos.operators.spectral.SpectralFilter.influence`), its kernel cut where it
        holds all but INFLUENCE_ENERGY_TOL of its energy and convolved on the grid that
        needs (+-25-45 lags and +-1-4 cells at 16 ps and 1.9 cm: 0.56 M points where the
        slab grid has 4.2 M). For a tail-filled window it is the plain filter's: the fill
        restores the unseen tail the filter then sees."""
        self.deconv.set_snr(snr)
        return self.deconv.influence(in_shape=self.shape, energy_tol=INFLUENCE_ENERGY_TOL)

    def _noise_like(self, transient: np.ndarray, scale: float, deconv, snr: float,
                    seed: int = NOISE_PROBE_SEED) -> cla.Array:
        """A realisation of the noise of the transient the inversion receives: Gaussian of
        the capture's Poisson variance (each bin's count; ``transient`` holds counts), seed
        ``seed`` (default NOISE_PROBE_SEED), through the same linear steps as the data
        (preprocessing, the normalisation ``scale``: :meth:`_noise_preprocessed`; the slab
        deconvolution ``deconv`` at ``snr`` when not None, the guard bins dropped): the
        noise spectrum of :meth:`clnlos.inverse.lct.LCT.upre_snr`.
        """
        t = self._noise_preprocessed(transient, scale, seed)
        if deconv is not None:
            deconv.set_snr(snr)
            t = deconv(t)
        return t[:self.shape[0]] if self.n_guard else t

    def _noise_preprocessed(self, transient: np.ndarray, scale: float,
                            seed: int = NOISE_PROBE_SEED) -> cla.Array:
        """The noise realisation of :meth:`_noise_like` preprocessed and normalised (guard
        bins kept), drawn block by block of rows (the same stream as one draw; no
        float64 temporary of the capture's size)."""
        y = np.asarray(transient)
        rng = np.random.default_rng(seed)
        n = np.empty(y.shape, self.dtype)
        rows = max(1, (1 << 20) // max(1, int(np.prod(y.shape[1:]))))
        for r0 in range(0, y.shape[0], rows):
            blk = y[r0:r0 + rows]
            n[r0:r0 + rows] = np.sqrt(np.maximum(blk, 0), dtype=np.float64) * \
                rng.standard_normal(blk.shape)
        t = self.pre(cla.to_device(self.queue, n))
        if scale != 1.0:
            self._scale_inplace(t, scale)
        return t

    def _probe(self, prep: PreparedCapture, deconv, snr: float) -> cla.Array:
        """:meth:`_noise_like` of a prepared capture (its preprocessed part kept in
        ``prep``: the same for every candidate of a search), deconvolved by ``deconv`` at
        ``snr`` (a tail fill's memo kept too)."""
        if prep.noise_tau is None:
            prep.noise_tau = self._noise_preprocessed(prep.transient, prep.scale)
        t = prep.noise_tau
        if deconv is not None:
            deconv.set_snr(snr)
            t = (deconv(t, prep.noise_fills) if isinstance(deconv, TailFilledDeconvolution)
                 else deconv(t))
        return t[:self.shape[0]] if self.n_guard else t

    def result_notes(self, volume: np.ndarray, noise: NoiseEstimate, params: dict,
                     transient: np.ndarray) -> list[str]:
        """One line each for a result that holds little or nothing, naming the cause: a
        volume of fewer than MIN_DEPTH_BINS depth bins, a kept window that ends before the
        capture's first arrival, a capture with no light above its background, a
        configured depth_min_m behind the first arrival, an all-zero volume."""
        out = []
        n, dz = self.shape[0], C0 * self.bin_width_s / 2
        c = self.config
        if n < MIN_DEPTH_BINS:
            k0, k1 = self.raw_window
            cause = (f"bins = {c.bins}" if c.bins is not None and c.bins < MIN_DEPTH_BINS
                     else f"max_path_m = {c.max_path_m:g} m keeps {n * dz * 2:.3g} m of path"
                     if c.max_path_m is not None
                     else f"the capture has {k1 - k0} bin(s) after t = 0")
            out.append(f"the volume has {n} depth bin(s) of {dz:.3g} m: {cause}; there is "
                       "no depth to resolve")
        behind = self._support_behind_arrival(noise)
        if behind:
            out.append(behind)
        raw = np.asarray(transient)
        whole = (noise if self.raw_window == (0, raw.shape[0]) else
                 estimate_noise(raw, self.raw_bin_width_s, self.raw_start_s))
        end_path = 2 * n * dz
        if whole.first_arrival_s is not None and C0 * whole.first_arrival_s >= end_path:
            out.append(f"the kept window ends at {end_path:.3g} m of path, before the "
                       f"capture's first arrival at {C0 * whole.first_arrival_s:.3g} m: the "
                       "volume holds none of the scene's light (a longer max_path_m)")
        elif whole.first_arrival_s is None:
            out.append("no bin of the capture rises above its background (the level of its "
                       f"first {100 * LEAD_FRACTION:g}% of bins) by {ARRIVAL_SIGMAS:g} noise "
                       "standard deviations: the volume shows noise, not a hidden scene")
        if not np.any(volume):
            out.append("the volume is all zero: " + self._empty_cause(noise, params))
        return out

    def _support_behind_arrival(self, noise: NoiseEstimate) -> str | None:
        """A configured depth_min_m behind the capture's first arrival (the method puts
        the nearest light deeper than it is), or None."""
        c, near = self.config, noise.nearest_depth_m
        if isinstance(c.depth_min_m, int | float) and near is not None \
                and c.depth_min_m > near:
            return (f"depth_min_m = {c.depth_min_m:g} m starts the volume behind the "
                    f"capture's first arrival ({near:.3g} m): what lies in front of it is "
                    "placed deeper or lost")
        return None

    def _empty_cause(self, noise: NoiseEstimate, params: dict) -> str:
        """Why an inversion returned nothing, from what the user set."""
        c = self.config
        if self._support_behind_arrival(noise):
            return "depth_min_m (above)"
        used = params.get("l1_weight_used")
        if isinstance(c.l1_weight, int | float) and used is not None and used >= 1:
            return (f"l1_weight = {c.l1_weight:g} (relative to max L^T I) sets every voxel "
                    "to zero (any weight of 1 or more does)")
        return f"method {c.method} returned no signal from this capture"

    def _resampling_note(self, snr: float, free: float, time_shifts) -> str:
        """One line: the slab SNR a resampling bounded, and why."""
        how = []
        if self._rebin_snr is not None and math.isfinite(self._rebin_snr):
            how.append(f"rebinned from {self.raw_bin_width_s * 1e12:.3g} ps to "
                       f"{self.bin_width_s * 1e12:.3g} ps bins")
        if time_shifts is not None and np.ptp(np.asarray(time_shifts) % 1.0) > 0:
            how.append("its columns moved by different fractions of a bin when read")
        return (f"the time axis was resampled ({' and '.join(how) or 'preprocessing'}): the "
                f"slab deconvolution stops at SNR {snr:.3g}, the deepest the resampled model "
                f"represents (it would be {free:.3g} without the resampling)")

    def _deconvolution_for(self, profile, noise: NoiseEstimate, snr: float, params: dict,
                           notes: list[str]):
        """The slab deconvolution for this capture: the plain Wiener filter, or where the
        time window ends before the blur of its latest arrivals has decayed (more than
        :func:`cut_level` of the peak still arriving in its last ``peak`` bins, and fewer
        than GUARD_PEAKS peak lags of guard bins between the volume's end and the cut) the
        :class:`~clnlos.inverse.tail_fill.TailFilledDeconvolution` on the window padded by the
        blur's
        reach (built on first use), with a note saying which depths rest on the rise of
        their response only."""
        scales = self.blur_scales
        n_scan = self.shape[1] * self.shape[2]
        background = noise.background_per_bin * n_scan * self.bin_width_s / self.raw_bin_width_s
        level = window_end_level(profile, background=background, end_bins=scales.peak_lags,
                                 photon_counts=noise.photon_counts, sigma=noise.sigma,
                                 n_scan=n_scan)
        params["window_end_level"] = level
        if level <= cut_level(snr) or self.n_guard >= GUARD_PEAKS * scales.peak_lags:
            return self.deconv
        if self._tail_deconv is None:
            self._tail_deconv = TailFilledDeconvolution(self.config.slab, (profile.size,)
                                                        + self.shape[1:], **self._deconv_args)
        dt, dz = self.bin_width_s, C0 * self.bin_width_s / 2
        n_data, n_out = profile.size, self.shape[0]
        params["tail_fill_bins"] = scales.reach_lags
        trusted = min(n_out, n_data - scales.peak_lags)
        msg = (f"the time window ends {n_data * dt * 1e9:.3g} ns after t = 0 with "
               f"{100 * level:.2g}% of the peak still arriving: the slab blur's unseen tail "
               f"({scales.reach_lags * dt * 1e9:.3g} ns) is predicted from the model")
        if trusted < n_out:
            msg += (f"; depths past {max(trusted, 0) * dz:.3g} m (of {n_out * dz:.3g} m) are "
                    f"left empty: only the rise of their response is inside the window (a "
                    f"longer capture, or --max-path {2 * max(trusted, 1) * dz:.3g} to stop "
                    f"the volume there)")
        notes.append(msg)
        return self._tail_deconv


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


def reconstruct(capture: Capture, config: ReconstructionConfig, *, dtype=np.float32,
                device=None, keep_transient: bool = False, progress=None,
                setup=None) -> Reconstruction:
    """Reconstruct an albedo volume from a capture with the given configuration.

    Pipelines (PSFs, spectra, FFT plans) are kept in :data:`clnlos.runtime.caches.PIPELINES` (LRU
    under a byte budget), so many captures of one geometry (a study) pay the set-up once.
    ``progress(k, n)`` follows the iterative method's iterations and ``setup(step)`` names
    each set-up step (pipeline, operator, step size, warm start) as it starts.
    """
    capture, reader_notes = without_direct(capture, config.direct_cut_s)
    if capture.bin_width_s is not None or config.bin_width_s is not None:
        bw = config.bin_width_s or capture.bin_width_s
        start = config.start_s if config.start_s is not None else capture.start_s
        kept, _ = preprocess_bins(capture.transient.shape[0], bw, start,
                                  config.max_path_m, None)
        config, notes = format_defaults(capture.attrs, config, bins_kept=kept, bin_width_s=bw)
        reader_notes += notes
    bw, start, sw = resolve_geometry(capture, config)
    queue = get_queue(device)
    key = (capture.transient.shape, bw, start, sw, json.dumps(config.as_attrs(), sort_keys=True),
           np.dtype(dtype).str, queue)
    pipe = PIPELINES.get(key, lambda: ReconstructionPipeline(
        capture.transient.shape, bin_width_s=bw, start_s=start, scan_width_m=sw,
        config=config, dtype=dtype, queue=queue, setup=setup), queue)
    rec = pipe.run(capture.transient, keep_transient=keep_transient, progress=progress,
                   model_snr=model_snr_for(capture, config), setup=setup,
                   time_shifts=capture.time_shift_bins)
    note = aligned_window_note(capture)
    if note:
        rec.notes.insert(0, note)
    rec.notes[:0] = reader_notes
    rec.extents = centred_extents(rec.extents, capture.scan_center_m)
    return rec


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









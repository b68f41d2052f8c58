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

from clnlos.brdf.lobes import AUTO
from clnlos.config import ReconstructionConfig
from clnlos.errors import InputFileError
from clnlos.forward.blur import blur_time_scales, confocal_lag_energy, confocal_psf, slab_blur
from clnlos.inverse.brdf_choice import (
    LOBE_NOT_SEARCHED,
    LOBE_NOT_SEARCHED_REASON,
    lobe_choice_note,
)
from clnlos.inverse.capture_defaults import format_defaults
from clnlos.inverse.gcv import GcvBins, binned_power
from clnlos.inverse.methods import METHODS, InversionGrid, method_class
from clnlos.inverse.parameter_choice import (
    SPLIT_EMPTY,
    SPLIT_EMPTY_REASON,
    NoiseProbe,
    ParameterSearches,
    PreparedCapture,
    auto_snrs,
    method_slab_snr,
    model_snr_for,
)
from clnlos.inverse.preprocessing import (
    GUARD_PEAKS,
    MIN_DEPTH_BINS,
    aligned_window_note,
    bandwidth_bins,
    bins_for,
    centred_extents,
    cut_level,
    describe_slab,
    preprocess_bins,
    preprocess_matrix,
    resolve_geometry,
    window_end_level,
)
from clnlos.inverse.snr import (
    ARRIVAL_SIGMAS,
    LEAD_FRACTION,
    SNR_MAX,
    SNR_MIN,
    NoiseEstimate,
    background_subtracted,
    column_shift_error,
    combined_accuracy,
    estimate_noise,
    rebinning_error,
    represented_snr,
)
from clnlos.inverse.tail_fill import TailFilledDeconvolution
from clnlos.io.capture import Capture, without_direct
from clnlos.operators.resample import AxisResample
from clnlos.physics.constants import C0
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


INFLUENCE_ENERGY_TOL = 1e-5  # the slab influence's kernel keeps all but this of its energy


class ReconstructionPipeline(ParameterSearches):
    """The composed stages for one capture geometry (shape, bin width, scan width);
    ``setup(step)`` names each step of the construction as it starts."""

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
            d = self.deconv
            self._gcv_slab = GcvBins.from_blocks(d.stored_gain_rows, d.fft.spec_shape,
                                                 d.pad_shape[2], folded=d.folded)
        bins = self._gcv_slab
        sums = binned_power(bins, self.deconv.power_blocks(row_blocks(bins.spectrum_shape), tau))
        return bins.snr_of(sums, SNR_MIN, SNR_MAX)

    # set on the class: called as stage_hook(name, True) when a timed stage starts and
    # (name, False) when it has ended (a profiler's labels: clnlos.bench.cold_process)
    stage_hook = None

    def _timed(self, timings, name, fn, *a, **kw):
        self.queue.finish()
        hook = type(self).stage_hook  # a plain function (not bound to the pipeline)
        if hook is not None:
            hook(name, True)
        t0 = time.perf_counter()
        try:
            out = fn(*a, **kw)
            self.queue.finish()
        finally:
            if hook is not None:
                hook(name, False)
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
                lobe_params["brdf_choice_s"] = timings["choose_brdf"]
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

    def without_floor(self, transient: np.ndarray, noise: NoiseEstimate | None = None
                      ) -> cla.Array:
        """The raw transient less its background floor (:func:`background_subtracted`;
        ``noise`` its :meth:`raw_noise`, measured here when None), on the device: where the
        preprocessing of a capture and of either half of its split starts."""
        noise = self.raw_noise(transient) if noise is None else noise
        return cla.to_device(self.queue, np.ascontiguousarray(
            background_subtracted(transient, noise, self.dtype)))

    def prepare(self, transient: np.ndarray, noise: NoiseEstimate | None = None,
                timings: dict | None = None) -> PreparedCapture:
        """The capture preprocessed and normalised once (:class:`PreparedCapture`), for
        :meth:`_reconstruct` (every candidate of a split search reuses it)."""
        noise = self.raw_noise(transient) if noise is None else noise
        x = self.without_floor(transient, noise)
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
        elif "brdf_chosen" in (lobe_params or {}) and snrs is None and slab_snr_factor is None:
            notes.append(lobe_choice_note(lobe_params))
        if math.isfinite(resampled) and self.deconv is not None:
            params["resampling_snr"] = resampled
            free = auto_snrs(noise, self.config, unbounded, data_snr=data_snr)[0]
            if snrs is None and snr < free / 2:
                notes.append(self._resampling_note(snr, free, time_shifts))
        named = self.config.snr_rule
        if named in ("thinning", "reproducibility") and cv is None and (
                slab_snr_factor is None and snrs is None):
            notes.append(f"snr_rule {named} not applied (it needs an \"auto\" slab SNR, a "
                         "slab and photon counts with light above their background): the "
                         "GCV rule or the configured SNRs")
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
        probe = (NoiseProbe(lambda: self._probe(prep, deconv, snr),
                            None if deconv is not None else lambda: self._noise_columns(prep))
                 if noise.photon_counts and not noise.noise_free else None)
        influence = (None if self.deconv is None else
                     lambda: self._slab_influence(snr))
        params.update(self.invert.configure(
            tau, noise, inv_snr, lambda name, fn, *a: self._timed(timings, name, fn, *a),
            probe, influence, **({} if inv_rule is None else {"rule": inv_rule})))
        del probe, influence  # the noise realisation freed before the volume is made
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
                added["tail_fill_block"] = deconv.block  # scan cells per side it summed
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
    def result_notes(self, volume: np.ndarray, noise: NoiseEstimate, params: dict,
                     transient: np.ndarray) -> list[str]:
        """One line each for a result that holds little or nothing, naming the cause: a
        volume of fewer than MIN_DEPTH_BINS depth bins, a kept window that ends before the
        capture's first arrival, a capture with no light above its background, a
        configured depth_min_m behind the first arrival, a volume cut at the last light
        (LCT), an all-zero volume."""
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
        end = params.get("depth_end_m")
        if end is not None:
            out.append(f"the volume ends at {end:.3g} m (0 behind it): no light rises above the "
                       f"background after {2 * end:.3g} m of path, and a point deeper would "
                       "send its light later (the late bins' noise left out)")
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
        """The slab deconvolution for this capture: the plain Wiener filter (always where no
        light rises above the capture's background: ``noise.first_arrival_s`` None), or where
        the time window ends before the blur of its latest arrivals has decayed (more than
        :func:`cut_level` of the peak still arriving in its last ``peak`` bins, and fewer
        than GUARD_PEAKS peak lags of guard bins between the volume's end and the cut) the
        :class:`~clnlos.inverse.tail_fill.TailFilledDeconvolution` on the window padded by the
        blur's
        reach (built on first use), with a note saying which depths rest on the rise of
        their response only."""
        scales = self.blur_scales
        n_scan = self.shape[1] * self.shape[2]
        if noise.first_arrival_s is None:  # no light above the floor (not subtracted then):
            params["window_end_level"] = 0.0  # none arrives at the end, no blur tail to fill
            return self.deconv
        # the profile was taken after background_subtracted (prepare, _held_out): no floor left
        level = window_end_level(profile, background=0.0, end_bins=scales.peak_lags,
                                 photon_counts=noise.photon_counts, sigma=noise.sigma,
                                 n_scan=n_scan)
        params["window_end_level"] = level
        if level <= cut_level(snr) or self.n_guard >= GUARD_PEAKS * scales.peak_lags:
            return self.deconv
        if self._tail_deconv is None:
            self._tail_deconv = TailFilledDeconvolution(
                self.config.slab, (profile.size,) + self.shape[1:], window_filter=self.deconv,
                **self._deconv_args)
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


def reconstruct(capture: Capture, config: ReconstructionConfig, *, dtype=np.float32,
                device=None, keep_transient: bool = False, progress=None,
                setup=None) -> Reconstruction:
    """Reconstruct an albedo volume from a capture with the given configuration.

    Pipelines (PSFs, spectra, FFT plans) are kept in :data:`clnlos.runtime.caches.PIPELINES` (LRU
    under a byte budget), so many captures of one geometry (a study) pay the set-up once.
    ``progress(k, n)`` follows the iterative method's iterations and ``setup(step)`` names
    each set-up step (pipeline, operator, step size, warm start) as it starts. A pipeline
    built for this call records its set-up as the stage "plan" of the timings.
    """
    capture, reader_notes = without_direct(capture, config.direct_cut_s,
                                           bin_width_s=config.bin_width_s,
                                           start_s=config.start_s,
                                           scan_width_m=config.scan_width_m)
    if capture.bin_width_s is not None or config.bin_width_s is not None:
        bw = config.bin_width_s or capture.bin_width_s
        start = config.start_s if config.start_s is not None else capture.start_s
        kept, _ = preprocess_bins(capture.transient.shape[0], bw, start,
                                  config.max_path_m, None)
        config, notes = format_defaults(capture.attrs, config, bins_kept=kept, bin_width_s=bw)
        reader_notes += notes
        above = METHODS[config.method].sum_bins_above if config.method in METHODS else None
        if config.bins is None and "bins" not in config.user_fields and above is not None:
            bins, note = bandwidth_bins(capture.transient, bins_kept=kept, bin_width_s=bw,
                                        start_s=start, above=above)
            if bins is not None:
                config = config.replace(bins=bins)
                reader_notes.append(note)
    bw, start, sw = resolve_geometry(capture, config)
    queue = get_queue(device)
    key = (capture.transient.shape, bw, start, sw, json.dumps(config.as_attrs(), sort_keys=True),
           np.dtype(dtype).str, queue)
    built: list[float] = []

    def build() -> ReconstructionPipeline:
        t0 = time.perf_counter()
        plan = ReconstructionPipeline(
            capture.transient.shape, bin_width_s=bw, start_s=start, scan_width_m=sw,
            config=config, dtype=dtype, queue=queue, setup=setup)
        queue.finish()
        built.append(time.perf_counter() - t0)
        return plan

    pipe = PIPELINES.get(key, build, queue)
    rec = pipe.run(capture.transient, keep_transient=keep_transient, progress=progress,
                   model_snr=model_snr_for(capture, config), setup=setup,
                   time_shifts=capture.time_shift_bins)
    if built:  # a plan built for this capture (none kept): its set-up is a stage of the run
        rec.timings_s = {"plan": built[0], **rec.timings_s}
    note = aligned_window_note(capture)
    if note:
        rec.notes.insert(0, note)
    rec.notes[:0] = reader_notes
    rec.extents = centred_extents(rec.extents, capture.scan_center_m)
    return rec

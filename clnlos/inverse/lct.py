"""Confocal inversion by the light-cone transform (O'Toole, Lindell & Wetzstein, Nature 2018).

With r = c t / 2, v = r^2 and u = z^2, the confocal measurement of an albedo volume
rho(x, y, z) (Lambertian falloff 1/r^4)::

    r^4 tau(x, y, r) = 2 r iiint rho(x', y', z) delta(r^2 - |x-x'|^2 - |y-y'|^2 - z^2)

becomes a 3D convolution in (v, y, x): v^{3/2} tau(sqrt v) = h * [rho(sqrt u) / sqrt u] with
the light cone h(x, y, v) = delta(v - x^2 - y^2). The inverse:

1. weight tau by (t/T)^p (p = ``falloff``: 4 for diffuse, 2 for retroreflective surfaces) and
   resample t -> v with mass-conserving bin overlaps (density 1/(2r): together r^3 tau);
2. Wiener-filter in (v, y, x) with the light cone: conj(H)/(|H|^2 + 1/SNR), zero padded to
   (2M, 2Ny, 2Nx), light cone splatted linearly between v bins (no aliasing);
3. resample u -> z (mass-conserving), clamp at 0.

Input: transient [t, y, x], bin 0 starting at t = 0 (round trip from the scan plane), nt bins
of ``bin_width_s``, scan of width ``scan_width_m`` (cell centres). Output: albedo volume
[z, y, x], depth bin k covering [k, k+1) * c * bin_width_s / 2, same lateral grid.
Left out: surface normals and BRDF (assumed isotropic scatterers), occlusions.
Behind a slab the input is the slab's Wiener deconvolution, whose leftover smoothing this
closed form cannot model (it acts in t, the light cone in v): :class:`LCTMethod` asks the
pipeline for a deeper one than cross-validation's (CLOSED_FORM_SLAB_SNR_MIN,
:mod:`clnlos.inverse.pipeline`).
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla
import scipy.sparse as sp

from clnlos.physics.constants import C0
from clnlos.checks import real
from clnlos.config import FALLOFF_RANGE, METHOD_FALLOFF
from clnlos.errors import ParameterError, ShapeError
from clnlos.inverse.gcv import GcvBins, binned_power, row_counts
from clnlos.inverse.methods import Inversion, InversionGrid
from clnlos.inverse.snr import (
    CLOSED_FORM_SLAB_SNR_MIN,
    LIGHTCONE_RULE,
    LIGHTCONE_SNR_MAX,
    LIGHTCONE_SNR_MIN,
)
from clnlos.operators.base import LinearOperator
from clnlos.operators.resample import AxisResample, overlap_matrix
from clnlos.operators.spectral import SpectralFilter, fold_spectrum, folded_shape
from clnlos.physics.grid import grid_offsets, row_blocks
from clnlos.physics.lightcone import lightcone_psf_grid
from clnlos.runtime.buffers import Scratch, fill_zero, kernel_int, round_up
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.fft import RealFFT3
from clnlos.runtime.programs import get_kernels, real_defines

DEFAULT_FALLOFF = METHOD_FALLOFF["lct"]  # diffuse (Lambertian) surfaces
DEFAULT_SNR = 1e2  # light-cone Wiener SNR when none is given


def check_inversion_args(shape, falloff: float) -> tuple[int, int, int]:
    """Validated (nt, ny, nx) and radiometric exponent of a confocal inversion plan."""
    nt, ny, nx = (int(s) for s in shape)
    if min(nt, ny, nx) < 1:
        raise ParameterError("shape", shape, "three sizes >= 1")
    real("falloff", falloff, *FALLOFF_RANGE)
    return nt, ny, nx


def lightcone_psf(nt: int, ny: int, nx: int, *, bin_width_s: float, pitch_m: float
                  ) -> np.ndarray:
    """Light cone h on the padded (2nt, 2ny, 2nx) v-grid in wrap order, unit sum (float64).

    For a lateral offset q = (dy^2 + dx^2) pitch^2 the response sits at v-shift
    s = q / R^2 * nt bins (R = nt c dt / 2), split linearly between bins floor(s), floor(s)+1.
    """
    R = nt * C0 * bin_width_s / 2
    oy, ox = grid_offsets(2 * ny, pitch_m), grid_offsets(2 * nx, pitch_m)
    q = oy[:, None] ** 2 + ox[None, :] ** 2
    psf = lightcone_psf_grid(q / R**2 * nt, 2 * nt, 2 * nt - 1)
    return psf / psf.sum()


def lightcone_psf_device(nt: int, ny: int, nx: int, *, bin_width_s: float, pitch_m: float,
                         dtype=np.float32, queue=None, out_g=None):
    """(:func:`lightcone_psf` built by ``kernels/lct.cl`` on the device (no host table), the
    number of leading v rows that hold it): into ``out_g`` (a (2 nt, 2 ny, 2 nx) array)
    when given; the normalisation (sum of the kept weights) is computed on the host in
    float64. The cone reaches v = (largest lateral offset / R)^2 nt: about half the padded
    rows stay zero, which the FFT of the plan skips."""
    q = get_queue(queue)
    dt = require_dtype(q.device, dtype)
    R = nt * C0 * bin_width_s / 2
    c = pitch_m**2 / R**2 * nt  # v-shift (bins) per squared cell offset
    j_y, j_x = grid_offsets(2 * ny, 1.0), grid_offsets(2 * nx, 1.0)
    s = (j_y[:, None] ** 2 + j_x[None, :] ** 2) * c
    k0, f = np.floor(s), s - np.floor(s)
    total = float(np.sum(np.where(k0 < 2 * nt, 1 - f, 0) + np.where(k0 + 1 < 2 * nt, f, 0)))
    psf = cla.empty(q, (2 * nt, 2 * ny, 2 * nx), dt) if out_g is None else out_g
    fill_zero(q, psf)
    k = get_kernels(q, "lct", real_defines(dt))
    k.lightcone_psf(q, (round_up(2 * nx, 16), round_up(2 * ny, 4)), None, psf.data,
                    kernel_int(2 * nt), kernel_int(2 * ny), kernel_int(2 * nx), dt.type(c),
                    dt.type(1.0 / total))
    rows = int(min(2 * nt, k0.max() + 2))  # bins floor(s) and floor(s) + 1
    return psf, rows


def t_to_v_matrix(nt: int, falloff: float) -> sp.csr_matrix:
    """Radiometric weight (t/T)^p then mass-conserving resampling t -> v = t^2 (normalised)."""
    t_edges = np.linspace(0.0, 1.0, nt + 1)
    v_edges_in_t = np.sqrt(np.linspace(0.0, 1.0, nt + 1))
    centres = (np.arange(nt) + 0.5) / nt
    return (overlap_matrix(t_edges, v_edges_in_t) @ sp.diags(centres**falloff)).tocsr()


def u_to_z_matrix(nt: int) -> sp.csr_matrix:
    """Mass-conserving resampling u = z^2 -> z (normalised)."""
    u_edges_in_z = np.sqrt(np.linspace(0.0, 1.0, nt + 1))
    return overlap_matrix(u_edges_in_z, np.linspace(0.0, 1.0, nt + 1))


class LCT:
    """LCT plan for transients of one shape, precision and device.

    Parameters: shape (nt, ny, nx); bin_width_s; scan_width_m (side of the scanned square,
    so the lateral pitch is scan_width_m / nx); snr of the light-cone Wiener filter;
    falloff exponent p; scratch: work buffers shared with a plan's other stages
    (:class:`clnlos.runtime.buffers.Scratch`); cache: an on-disk
    :class:`clnlos.runtime.spectrum_cache.SpectrumCache` for the light cone's spectrum.
    """

    def __init__(self, shape, *, bin_width_s: float, scan_width_m: float,
                 snr: float = DEFAULT_SNR, falloff: float = DEFAULT_FALLOFF, dtype=np.float32,
                 queue=None, scratch: Scratch | None = None, cache=None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        nt, ny, nx = self.shape = check_inversion_args(shape, falloff)
        self.bin_width_s, self.scan_width_m = float(bin_width_s), float(scan_width_m)
        pitch = self.scan_width_m / nx
        self.to_v = AxisResample(t_to_v_matrix(nt, falloff), (ny, nx), dtype=self.dtype,
                                 queue=self.queue)
        self.to_v.name = "lct_t_to_v"
        # the same resamplings writing into / reading from the padded (2 nt, 2 ny, 2 nx)
        # grid of the Wiener filter: no separate pad and crop passes
        self._to_v_padded = AxisResample(self.to_v.matrix, (ny, nx), dtype=self.dtype,
                                         queue=self.queue, out_plane=(2 * ny, 2 * nx),
                                         out_rows=2 * nt)
        scratch = Scratch(self.queue) if scratch is None else scratch
        self.cone = self._cone_filter(pitch, scratch, cache)

        self.cone.name = "lct_lightcone"
        self.inverse_filter = SpectralFilter.from_spectrum(self.cone, self.cone.H,
                                                           mode="wiener", snr=snr)
        self.to_z = AxisResample(u_to_z_matrix(nt), (ny, nx), dtype=self.dtype,
                                 queue=self.queue)
        self.to_z.name = "lct_u_to_z"
        self._to_z_padded = AxisResample(self.to_z.matrix, (ny, nx), dtype=self.dtype,
                                         queue=self.queue, in_plane=(2 * ny, 2 * nx))
        self._k = get_kernels(self.queue, "resample", real_defines(self.dtype))
        self._gcv_bins = None  # clnlos.inverse.gcv.GcvBins of the light cone, built on first use
        self._row_counts = None  # clnlos.inverse.gcv.row_counts of the bins, on first use

    def _cone_filter(self, pitch: float, scratch: Scratch, cache) -> SpectralFilter:
        """The light-cone convolution on the (2 nt, 2 ny, 2 nx) grid, its spectrum stored
        folded (:func:`clnlos.operators.spectral.fold_spectrum`: the cone is real and even
        in y and x; a quarter of the whole, 68 MB in place of 270 MB at 128 x 128 x 512):
        from the on-disk cache, else the FFT of :func:`lightcone_psf_device` (slot "a") into
        the work spectrum (slot "b") folded from there (stored when a cache is given)."""
        nt, ny, nx = self.shape
        pad = (2 * nt, 2 * ny, 2 * nx)
        kw = dict(mode="convolve", dtype=self.dtype, queue=self.queue, scratch=scratch,
                  spectrum_folded=True)
        fft = RealFFT3(pad, self.dtype, self.queue)
        key = None
        if cache is not None:
            key = cache.key("lightcone", shape=[nt, ny, nx], bin_width_s=self.bin_width_s,
                            pitch_m=pitch, dtype=self.dtype.name, folded=True)
            spec = cla.empty(self.queue, folded_shape(fft.spec_shape), fft.cdtype)
            if cache.load(key, spec):
                return SpectralFilter(pad, self.shape, spectrum=spec, **kw)
        psf, rows = lightcone_psf_device(nt, ny, nx, bin_width_s=self.bin_width_s,
                                         pitch_m=pitch, dtype=self.dtype, queue=self.queue,
                                         out_g=scratch.array("a", pad, self.dtype))
        whole = fft.forward(psf, scratch.array("b", fft.spec_shape, fft.cdtype),
                            nonzero=(rows,) + pad[1:])
        spec = fold_spectrum(whole)
        del psf, whole  # slots "a" and "b" are the filter's work buffers from now on
        cone = SpectralFilter(pad, self.shape, spectrum=spec, **kw)
        if cache is not None:
            cache.store(key, cone.H)
        return cone

    def set_snr(self, snr: float) -> None:
        """Change the SNR of the light-cone Wiener filter (no rebuild)."""
        self.inverse_filter.set_snr(snr)

    def gcv_snr(self, tau: cla.Array, snr_min: float, snr_max: float) -> float:
        """The light-cone Wiener SNR in [snr_min, snr_max] that generalised cross-validation
        (:mod:`clnlos.inverse.gcv`) picks for the transient ``tau`` [t, y, x] (device): V evaluated
        on the filter's own (v, y, x) grid, where the light cone is a convolution."""
        return self._bins().snr_of(self.power(tau), snr_min, snr_max)

    def upre_snr(self, tau: cla.Array, probe, snr_min: float, snr_max: float) -> float:
        """The light-cone Wiener SNR in [snr_min, snr_max] that the unbiased predictive risk
        estimate (:meth:`clnlos.inverse.gcv.GcvBins.upre_snr`) picks for the transient ``tau``
        whose noise ``probe`` describes (:class:`clnlos.inverse.parameter_choice.NoiseProbe`):
        on the filter's (v, y, x) grid, where the slab deconvolution and the t -> v resampling
        have coloured it (GCV's white-noise assumption does not hold there). The noise's
        power from its law where the probe has one (:meth:`column_noise_power`, no
        realisation and no FFT), else from the realisation ``probe()``. The data's spectrum
        stays in the filter's work buffer: the inversion of ``tau`` that follows reuses it
        (:meth:`__call__`, one forward FFT for the choice and the inversion together)."""
        columns = getattr(probe, "columns", None)
        noise = (self.column_noise_power(*columns()) if columns is not None
                 else self.power(probe()))
        return self._bins().upre_snr_of(self.power(tau), noise, snr_min, snr_max)

    def column_noise_power(self, K, d: np.ndarray) -> np.ndarray:
        """The expected power per bin of :meth:`_bins` of the noise n = K e of every scan
        column (e independent, variance ``d`` summed over the scan points) after the t -> v
        resampling and the padding: independent noise is white across the scan, so
        E|Y(k_v, k_y, k_x)|^2 = sum_t |(F_v M)(k_v, t)|^2 d(t), M = (t -> v) K, F_v the
        DFT over the 2 nt padded v bins -- the same at every lateral frequency."""
        nt = self.shape[0]
        M = (self.to_v.matrix @ K).tocsc()
        s_half = np.zeros(nt + 1)
        step = max(1, (1 << 22) // (2 * nt))  # raw columns per block: ~64 MB of spectrum
        for c0 in range(0, M.shape[1], step):
            c1 = min(M.shape[1], c0 + step)
            block = M[:, c0:c1].toarray() * np.sqrt(d[c0:c1])[None, :]
            f = np.fft.rfft(block, n=2 * nt, axis=0)
            s_half += (f.real ** 2 + f.imag ** 2).sum(axis=1)
        k = np.arange(2 * nt)
        if self._row_counts is None:  # once per plan: the bins' frequencies per v row
            self._row_counts = row_counts(self._bins())
        return s_half[np.minimum(k, 2 * nt - k)] @ self._row_counts

    def _bins(self):
        if self._gcv_bins is None:
            f = self.inverse_filter
            self._gcv_bins = GcvBins.from_blocks(f.stored_gain_rows, f.fft.spec_shape,
                                                 f.pad_shape[2], folded=f.folded)
        return self._gcv_bins

    def power(self, tau: cla.Array) -> np.ndarray:
        """|F[t -> v of tau, padded]|^2 on the half spectrum of the light-cone filter,
        summed per bin of :meth:`_bins` (block by block)."""
        bins = self._bins()
        return binned_power(bins, self.inverse_filter.power_blocks(
            row_blocks(bins.spectrum_shape),
            write_input=lambda buf: self._to_v_padded.apply_into(tau, buf), source=tau))

    @property
    def forward_operator(self) -> LinearOperator:
        """The linear model in the (v, y, x) domain used by the inverse: light-cone convolution."""
        return self.cone

    def __call__(self, tau):
        """Albedo volume [z, y, x] (clamped at 0) from a transient [t, y, x]; right after
        :meth:`upre_snr` or :meth:`gcv_snr` of the same ``tau``, with their forward
        transform (:meth:`clnlos.operators.spectral.SpectralFilter.filter_padded`)."""
        on_device = isinstance(tau, cla.Array)
        x = tau if on_device else cla.to_device(self.queue,
                                                np.ascontiguousarray(tau, self.dtype))
        if tuple(x.shape) != self.shape:
            raise ShapeError(f"LCT input: expected shape {self.shape}, got {tuple(x.shape)}")
        vol = cla.empty(self.queue, self.shape, self.dtype)
        self.inverse_filter.filter_padded(
            lambda buf: self._to_v_padded.apply_into(x, buf),
            lambda buf: self._to_z_padded.apply_into(buf, vol), source=x)
        self._k.clamp_nonnegative(self.queue, (round_up(vol.size, 256),), None, vol.data,
                                  np.int64(vol.size))
        return vol if on_device else vol.get()


def initial_inversion_snr(config) -> float:
    """The light-cone SNR a plan is built with: the configured number, or 1 for "auto"
    (set per capture by :meth:`LCTMethod.configure`)."""
    return 1.0 if config.inversion_snr == "auto" else float(config.inversion_snr)


def choose_lightcone_snr(lct: LCT, config, noise, tau_g, rule_snr: float, timed,
                         probe=None, rule: str | None = None) -> tuple[float, str | None]:
    """(light-cone Wiener SNR, rule) for this capture, within [LIGHTCONE_SNR_MIN,
    LIGHTCONE_SNR_MAX] when the config says "auto" and the capture is noisy: for photon
    counts the unbiased predictive risk estimate with the noise realisation ``probe()``
    (:meth:`LCT.upre_snr`; LIGHTCONE_RULE), else generalised cross-validation
    (:meth:`LCT.gcv_snr`); otherwise ``rule_snr`` (the configured number, or the photon rule
    on noise-free data) and rule None; ``rule_snr`` and ``rule`` where ``rule`` is given (a
    choice the pipeline made, :meth:`clnlos.inverse.methods.Inversion.configure`)."""
    if rule is not None:
        return rule_snr, rule
    if config.inversion_snr != "auto" or noise.noise_free:
        return rule_snr, None
    if noise.photon_counts and LIGHTCONE_RULE == "upre" and probe is not None:
        return timed("choose_inversion_snr", lct.upre_snr, tau_g, probe, LIGHTCONE_SNR_MIN,
                     LIGHTCONE_SNR_MAX), "upre"
    return timed("choose_inversion_snr", lct.gcv_snr, tau_g, LIGHTCONE_SNR_MIN,
                 LIGHTCONE_SNR_MAX), "gcv"


def lightcone_snr_params(snr: float, rule: str | None) -> dict:
    """What a volume records of the light-cone SNR choice."""
    return ({} if rule is None else {"inversion_snr_rule": rule}) | {"inversion_snr_used": snr}


def last_light_row(noise, nt: int, bin_width_s: float) -> int | None:
    """The first depth row of a volume of ``nt`` rows (bins of ``bin_width_s``, row k at
    depths [k, k+1) c dt / 2) that lies wholly behind the capture's last light
    (:attr:`clnlos.inverse.snr.NoiseEstimate.farthest_depth_m`): no hidden point is there;
    None where that is not measured or no row is behind it."""
    far = noise.farthest_depth_m
    if far is None:
        return None
    k = math.ceil(far / (C0 * bin_width_s / 2) - 1e-9)
    return k if k < nt else None


class LCTMethod(Inversion):
    """``method = "lct"`` (:class:`LCT` behind the inversion contract of
    :mod:`clnlos.inverse.methods`). The volume ends where the capture's light does: the
    rows behind its last light (:func:`last_light_row`) are zeroed, the late bins' noise
    that the weighting (t/T)^p lifts most and a front view (max over depth) would show."""

    name = "lct"
    slab_snr_min = CLOSED_FORM_SLAB_SNR_MIN  # Phi not modelled (clnlos.inverse.pipeline)
    lightcone_filter = True

    def __init__(self, grid: InversionGrid, config, *, dtype, queue, scratch=None,
                 cache=None):
        super().__init__(grid, config, dtype=dtype, queue=queue, scratch=scratch, cache=cache)
        self.lct = LCT(grid.shape, snr=initial_inversion_snr(config), **self.falloff(),
                       **self.geometry(), cache=cache)
        self.end_row: int | None = None  # the first row behind the last light, per capture

    def configure(self, tau_g, noise, rule_snr: float, timed, probe=None,
                  slab_influence=None, rule: str | None = None) -> dict:
        snr, rule = choose_lightcone_snr(self.lct, self.config, noise, tau_g, rule_snr, timed,
                                         probe, rule)
        self.lct.set_snr(snr)
        self.end_row = last_light_row(noise, self.grid.shape[0], self.grid.bin_width_s)
        ends = ({} if self.end_row is None else
                {"depth_end_m": self.end_row * C0 * self.grid.bin_width_s / 2})
        return lightcone_snr_params(snr, rule) | ends

    def __call__(self, tau_g, *, progress=None, setup=None):
        vol = self.lct(tau_g)
        if self.end_row is not None:
            vol[self.end_row:].fill(0)
        return vol

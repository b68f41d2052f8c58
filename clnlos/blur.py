"""The confocal slab blur Phi * Phi on the zero-padded measurement grid.

Light crosses the slab twice in a confocal CDT capture (laser in, return out), so the
measurement is tau = (Phi * Phi) * I with * a 3D convolution over (t, y, x) and Phi the
slab transmittance of :mod:`clnlos.diffusion` on the scan grid (Lindell & Wetzstein 2020,
Eq. 11). Grid conventions are those of :func:`clnlos.diffusion.diffusion_psf`: zero lag and
zero offset at index [0, 0, 0], wrap order, no half-pixel shift.

Left out: the lateral tails of Phi * Phi beyond one scan width (they alias on the 2N
padded grid; the CDT slab's blur is a few cm against scan widths of tens of cm).
:func:`lateral_reach_m` says how far the blur reaches, so that a forward model can compute
the hidden-side transient I on a grid that extends that far past the scan area.
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla

from .diffusion import (SUPPORT_TOL, SlabTransmittance, diffusion_psf, diffusion_psf_device,
                        lateral_integral_profile, support_of)
from .slab import Slab
from .fft import RealFFT3
from .runtime import (
    fill_zero,
    get_kernels,
    get_queue,
    has_fp64,
    real_defines,
    require_dtype,
    round_up,
    zeros,
)
from .wiener import SpectralFilter


def _phi_on_padded_grid(slab: Slab, shape, *, bin_width_s: float, pitch_m: float,
                        n_dipoles, periodic_xy: bool, dtype, queue):
    """(Phi on the padded grid, zero past its temporal support; the energy fraction of
    Phi * Phi at lags >= nt)."""
    q = get_queue(queue)
    dt = require_dtype(q.device, dtype)
    nt, ny, nx = (int(s) for s in shape)
    pad = (2 * nt, ny, nx) if periodic_xy else (2 * nt, 2 * ny, 2 * nx)
    phi_g = zeros(q, pad, dt)  # lags past the support (and nt..2nt-1) stay 0
    prof = lateral_integral_profile(slab, nt=nt, bin_width_s=bin_width_s, queue=q)
    lags = support_of(prof)
    diffusion_psf_device(SlabTransmittance(slab, n_dipoles=n_dipoles, dtype=dt, queue=q),
                         nt=nt, bin_width_s=bin_width_s, ny=pad[1], nx=pad[2],
                         pitch_m=pitch_m, lags=lags, out_g=phi_g)
    return phi_g, confocal_tail_fraction(prof[:lags], nt)


def confocal_tail_fraction(prof: np.ndarray, nt: int) -> float:
    """Energy fraction of Phi * Phi at lags >= nt, from the laterally integrated profile
    (lateral integration commutes with the convolution: it is prof * prof in time)."""
    p2 = np.convolve(prof, prof)
    total = p2.sum()
    return float(p2[nt:].sum() / total) if total > 0 else 0.0


def _squared_spectrum(phi_g: cla.Array) -> tuple[RealFFT3, cla.Array]:
    """(the FFT plan of phi_g's grid, F[phi_g]^2): the spectrum of Phi * Phi, uncut."""
    q = phi_g.queue
    fft = RealFFT3(phi_g.shape, phi_g.dtype, q)
    spec = fft.forward(phi_g)
    k = get_kernels(q, "wiener", real_defines(phi_g.dtype))
    k.spectral_square(q, (round_up(spec.size, 256),), None, spec.data, np.int64(spec.size))
    return fft, spec


def _cut_at_window(fft: RealFFT3, spec: cla.Array, out_g: cla.Array, nt: int) -> cla.Array:
    """Phi * Phi in the lag domain (into ``out_g``), zero at lags >= nt."""
    phi2 = fft.inverse(spec, out_g)
    fill_zero(phi2.queue, phi2,
              offset_bytes=nt * phi2.shape[1] * phi2.shape[2] * phi2.dtype.itemsize)
    return phi2


def confocal_spectrum(slab: Slab, shape: tuple[int, int, int], *, bin_width_s: float,
                      pitch_m: float, n_dipoles: int | None = None, periodic_xy: bool = False,
                      dtype=np.float32, queue=None):
    """(F[Phi * Phi] on the padded grid, the padded-grid buffer that held Phi -- free for
    reuse as scratch): the spectrum of :func:`confocal_psf` without going back to the lag
    domain when it need not.

    When Phi * Phi holds less than SUPPORT_TOL of its energy at lags >= nt
    (:func:`confocal_tail_fraction`), the cut at nt changes nothing that matters and the
    spectrum is F[Phi]^2 (one forward FFT instead of a forward, an inverse and a forward);
    otherwise it is F of :func:`confocal_psf`."""
    q = get_queue(queue)
    dt = require_dtype(q.device, dtype)
    nt = int(shape[0])
    phi_g, tail = _phi_on_padded_grid(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                                      n_dipoles=n_dipoles, periodic_xy=periodic_xy,
                                      dtype=dt, queue=q)
    fft, spec = _squared_spectrum(phi_g)
    if tail >= SUPPORT_TOL:
        spec = fft.forward(_cut_at_window(fft, spec, phi_g, nt), spec)
    return spec, phi_g


def confocal_psf(slab: Slab, shape: tuple[int, int, int], *, bin_width_s: float,
                 pitch_m: float, n_dipoles: int | None = None, periodic_xy: bool = False,
                 dtype=np.float32, queue=None) -> cla.Array:
    """Phi * Phi on the padded grid (2 nt, 2 ny, 2 nx) for transients of ``shape``.

    ``periodic_xy``: the grid is (2 nt, ny, nx), a convolution that wraps laterally -- for
    a forward model whose input already extends past the kept area by the blur's reach
    (:func:`lateral_reach_m`), where the wrapped border is cropped away.

    Phi is computed on the device with ``normalize="physical"`` (so the sum of Phi * Phi
    approximates the squared total transmittance) for the lags of its temporal support
    (:func:`~clnlos.diffusion.temporal_support_lags`, all but 1e-7 of its energy; zero
    after); the self-convolution is exact on the 2 nt grid and is then cut to lags
    0..nt-1, the only ones that reach the time window from inside it -- longer lags would
    wrap around the padded FFT.
    """
    q = get_queue(queue)
    dt = require_dtype(q.device, dtype)
    nt = int(shape[0])
    phi_g, _ = _phi_on_padded_grid(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                                   n_dipoles=n_dipoles, periodic_xy=periodic_xy, dtype=dt,
                                   queue=q)
    fft, spec = _squared_spectrum(phi_g)
    return _cut_at_window(fft, spec, phi_g, nt)


def lateral_reach_m(slab: Slab, *, window_s: float, pitch_m: float, tol: float = 1e-3,
                    n_dipoles: int | None = None, queue=None) -> float:
    """Radius R (m) outside which the confocal blur holds less than ``tol`` of its energy.

    With P(rho) = integral of Phi(t, rho) over lags 0..window_s (the light that can reach the
    time window), the confocal blur integrated over time is about P * P (2D convolution);
    R is the smallest offset with sum_{|rho| > R} (P * P) < tol * sum (P * P). The profile is
    computed on a grid of at most 256 cells per side reaching 20 (d + 2 z_e), a bound well
    past the lateral decay length (d + 2 z_e) / pi of the slab's diffuse spot.
    """
    from scipy.signal import fftconvolve

    r_max = 20.0 * (slab.thickness_m + 2.0 * slab.ze)
    pitch = max(float(pitch_m), 2.0 * r_max / 256)
    n = 2 * int(math.ceil(r_max / pitch))
    nt = 64
    q = get_queue(queue)
    phi = diffusion_psf(slab, nt=nt, bin_width_s=window_s / nt, ny=n, nx=n, pitch_m=pitch,
                        n_dipoles=n_dipoles, dtype=np.float64 if has_fp64(q.device) else
                        np.float32, queue=q)
    p = np.fft.fftshift(phi.astype(np.float64).sum(axis=0))  # centre (zero offset) at n/2
    pp = fftconvolve(p, p, mode="full")  # zero offset at index n
    off = (np.arange(2 * n - 1) - n) * pitch
    rho = np.hypot(off[:, None], off[None, :]).ravel()
    e = np.clip(pp.ravel(), 0, None)
    order = np.argsort(rho)
    outside = 1.0 - np.cumsum(e[order]) / e.sum()
    k = int(np.argmax(outside < tol))
    return float(rho[order][k])


def slab_blur(slab: Slab, shape, *, bin_width_s: float, pitch_m: float, mode: str = "convolve",
              snr: float | None = None, n_dipoles: int | None = None,
              lateral_pad: str = "zero", periodic_xy: bool = False, dtype=np.float32,
              queue=None) -> SpectralFilter:
    """The confocal blur as an operator on transients of ``shape`` [t, y, x].

    ``mode="convolve"``: the forward model tau = (Phi * Phi) * I in physical units (the DC
    gain is the squared slab transmittance). ``mode="wiener"``: the deconvolution
    conj(H)/(|H|^2 + 1/SNR) with H normalised to unit DC gain.
    """
    spec, scratch = confocal_spectrum(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                                      n_dipoles=n_dipoles, periodic_xy=periodic_xy,
                                      dtype=dtype, queue=queue)
    return SpectralFilter(tuple(scratch.shape), shape, mode=mode, snr=snr,
                          normalize=(mode == "wiener"), lateral_pad=lateral_pad, dtype=dtype,
                          queue=queue, spectrum=spec, work_buffer=scratch)

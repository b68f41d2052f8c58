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

import dataclasses
import math
from functools import lru_cache

import numpy as np
import pyopencl.array as cla
import scipy.fft as sfft
from scipy.special import erfc

from clnlos.diffusion import (
    SlabTransmittance,
    bin_time_nodes,
    diffusion_psf,
    lateral_integral_profile,
    support_of,
)
from clnlos.errors import ParameterError
from clnlos.operators.spectral import SpectralFilter, folded_shape
from clnlos.physics.grid import grid_offsets, padded_length
from clnlos.physics.slab import Slab
from clnlos.runtime.buffers import fill_zero, host_view
from clnlos.runtime.caches import CACHES, FORWARD_BLURS
from clnlos.runtime.device import get_queue, has_fp64, host_threads, require_dtype
from clnlos.runtime.fft import COMPLEX_OF, RealFFT3


def _padded_grid(shape, periodic_xy: bool) -> tuple[int, int, int]:
    """The slab filters' padded grid for transients of ``shape``: time to
    :func:`clnlos.physics.grid.padded_length` (at least 2 nt), laterally 2 ny x 2 nx (or
    ny x nx, ``periodic_xy``)."""
    nt, ny, nx = (int(s) for s in shape)
    pt = padded_length(nt)
    return (pt, ny, nx) if periodic_xy else (pt, 2 * ny, 2 * nx)


def cell_gaussian(offsets_m: np.ndarray, a_m2: np.ndarray, pitch_m: float) -> np.ndarray:
    """Fraction of the unit 1D Gaussian exp(-u^2 / a) / sqrt(pi a) in the cells of width
    ``pitch_m`` centred at ``offsets_m``, for each ``a_m2`` (m^2; shape (...) -> (..., n)):

        G(o) = [erfc((|o| - p / 2) / sqrt(a)) - erfc((|o| + p / 2) / sqrt(a))] / 2

    (the erfc form keeps the far cells' small values exact). Sums to 1 over an infinite row
    for any width: a Gaussian narrower than a cell keeps its mass in the cell at 0."""
    s = np.sqrt(np.asarray(a_m2, np.float64))[..., None]
    o = np.abs(np.asarray(offsets_m, np.float64))
    h = 0.5 * float(pitch_m)
    return 0.5 * (erfc((o - h) / s) - erfc((o + h) / s))


def _lateral_dfts(a: np.ndarray, pitch_m: float, ny: int, nx: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(Gy [..., ny], Gx [..., nx // 2 + 1]): the DFTs along y (whole) and x (half) of the
    cell-integrated unit Gaussians exp(-u^2 / a) / sqrt(pi a) on the wrap-order grids --
    real, because each row is circularly even."""
    gy = sfft.fft(cell_gaussian(grid_offsets(ny, pitch_m), a, pitch_m), axis=-1).real
    gx = sfft.rfft(cell_gaussian(grid_offsets(nx, pitch_m), a, pitch_m), axis=-1).real
    return gy, gx


def _node_masses(plan: SlabTransmittance, lags: int, bin_width_s: float, time_nodes: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(m [lag, node], u [node], a [lag, node]): the laterally integrated slab response
    carried by each Gauss-Legendre node of each lag bin, m = dt w_j T(0, t) pi a with
    a = 4 D v t (the plane integral of exp(-rho^2 / a) is pi a), so that sum_j m[k, j] is
    the bin's transmitted fraction; u the nodes in bins (t = (k + u) dt)."""
    t, w = bin_time_nodes(lags, bin_width_s, time_nodes)
    u = t[0] / float(bin_width_s) if lags else np.zeros(len(w))
    log_t0 = plan.log_series(t)
    alive = np.isfinite(log_t0) & (t > 0)
    a = 4.0 * plan.slab.D * plan.slab.v * np.where(alive, t, 1.0)  # 4 D v t (m^2)
    m = np.where(alive, w[None, :] * np.exp(np.where(alive, log_t0, 0.0)) * np.pi * a, 0.0)
    return m * float(bin_width_s), u, a


def phi_lateral_factors(plan: SlabTransmittance, *, lags: int, bin_width_s: float,
                        pitch_m: float, ny: int, nx: int, time_nodes: int = 4
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(c [lag, node], Gy [lag, node, ny], Gx [lag, node, nx // 2 + 1]), float64: the 2D
    lateral DFT of Phi at lag k is sum_j c[k, j] Gy[k, j, :, None] Gx[k, j, None, :].

    Phi[k, y, x] = dt sum_j w_j int_cell(y, x) T(rho, t_kj) d^2 rho -- the fraction of the
    light entering at the origin that leaves through the scan cell (y, x) in lag bin k --
    and T(rho, t) = T(0, t) exp(-rho^2 / (4 D v t)): each time node is a separable
    Gaussian of plane integral c = dt w_j T(0, t) 4 pi D v t, integrated over the cells
    (:func:`cell_gaussian`), whose 2D DFT is the product of two 1D DFTs."""
    c, _, a = _node_masses(plan, lags, bin_width_s, time_nodes)
    gy, gx = _lateral_dfts(a, pitch_m, ny, nx)
    return c, gy, gx


def confocal_lateral_factors(plan: SlabTransmittance, *, lags: int, rows: int,
                             bin_width_s: float, pitch_m: float, ny: int, nx: int,
                             time_nodes: int = 4
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The factors of :func:`phi_lateral_factors` for Phi * Phi itself, lags 0..rows-1.

    The two legs' lateral Gaussians convolve into one: exp(-u^2 / a1) * exp(-u^2 / a2) =
    pi a1 a2 / (a1 + a2) exp(-u^2 / (a1 + a2)) with a1 + a2 = 4 D v (t1 + t2), so

        (Phi * Phi)(u, t) = P2(t) exp(-u^2 / (4 D v t)) / (4 pi D v t),   P2 = P * P

    with P the laterally integrated response. On the bins, a pair of nodes (u1, u2) of
    lags (j, k - j) arrives at t = (k + u1 + u2) dt whatever j, so lag k is
    sum over node pairs of Q[k] G_t(y) G_t(x), Q[k] = sum_j m[j, n1] m[k - j, n2] (the
    discrete convolution of :func:`_node_masses`) and G_t the unit Gaussian of a = 4 D v t
    integrated over the scan cell (:func:`cell_gaussian`). The energy per lag is therefore
    that of the laterally integrated P * P at any pitch, and the lateral shape is the cell
    integral of the continuous blur (variance 2 D v t + p^2 / 12 per axis)."""
    q, t = _pair_masses(plan, lags, rows, bin_width_s, time_nodes)
    a = 4.0 * plan.slab.D * plan.slab.v * np.where(q > 0, t, float(bin_width_s))
    gy, gx = _lateral_dfts(a, pitch_m, ny, nx)
    return q, gy, gx


def _pair_masses(plan: SlabTransmittance, lags: int, rows: int, bin_width_s: float,
                 time_nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """(Q [lag, s], t [lag, s] in s): the laterally integrated Phi * Phi of lags 0..rows-1
    split by the sum s = u1 + u2 of the two legs' time nodes (:func:`_node_masses`), each
    part arriving at t = (k + s) dt (:func:`confocal_lateral_factors`); zero where nothing
    has arrived."""
    m, u, _ = _node_masses(plan, lags, bin_width_s, time_nodes)
    n = sfft.next_fast_len(2 * max(lags, 1), real=True)
    spec = sfft.rfft(m, n=n, axis=0)
    sums = np.round(u[:, None] + u[None, :], 12)
    keys = np.unique(sums)
    q = np.zeros((rows, keys.size))
    for i, j in np.ndindex(sums.shape):
        conv = sfft.irfft(spec[:, i] * spec[:, j], n=n)[:rows]
        q[:len(conv), np.searchsorted(keys, sums[i, j])] += conv
    t = (np.arange(rows)[:, None] + keys[None, :]) * float(bin_width_s)
    q = np.where((t > 0) & (q > 0), q, 0.0)  # FFT round-off where nothing has arrived
    return q, t


def confocal_lag_energy(slab: Slab, *, nt: int, bin_width_s: float,
                        n_dipoles: int | None = None, queue=None) -> np.ndarray:
    """sum over the plane of Phi * Phi per lag, lags 0..nt-1 (float64): the laterally
    integrated blur of :func:`confocal_psf` (the same bins and nodes), without its lateral
    grid."""
    q = get_queue(queue)
    prof = lateral_integral_profile(slab, nt=nt, bin_width_s=bin_width_s, queue=q)
    lags = support_of(prof)
    plan = SlabTransmittance(slab, n_dipoles=n_dipoles, dtype=np.float64 if has_fp64(q.device)
                             else np.float32, queue=q)
    energy, _ = _pair_masses(plan, lags, min(int(nt), 2 * lags), bin_width_s, 4)
    out = np.zeros(int(nt))
    out[:energy.shape[0]] = energy.sum(axis=1)
    return out


def _write_phi_spectrum(out: np.ndarray, factors, *, rows: int = 16) -> None:
    """out[w, ky, kx] <- the 3D half spectrum of the separable table the ``factors`` of
    :func:`phi_lateral_factors` or :func:`confocal_lateral_factors` describe (zero past
    their lags): the lateral spectra are built ``rows`` ky-rows at a time and transformed
    along t. Each (ky, kx) column is a real sequence, so the frequencies past n0 / 2 are
    the conjugates of those below; ``out`` is either the whole (n0, n1, n2h) spectrum or
    its folded (n0 / 2 + 1, n1 / 2 + 1, n2h) quarter
    (:func:`clnlos.operators.spectral.folded_shape`: the table is even in y too), told apart
    by its shape given n1 = Gy's length."""
    c, gy, gx = factors
    n1 = gy.shape[-1]
    folded = out.shape[1] != n1
    nh = out.shape[0] if folded else out.shape[0] // 2 + 1
    n0 = 2 * (nh - 1) if folded else out.shape[0]
    mirror = n0 - np.arange(nh, n0)  # F[n0 - w] = conj(F[w]) along t
    real = np.float32 if out.dtype == np.complex64 else np.float64
    for y0 in range(0, out.shape[1], rows):
        lat = np.matmul((gy[:, :, y0:y0 + rows] * c[:, :, None]).transpose(0, 2, 1), gx)
        if folded:
            lat = lat[:, :out.shape[1] - y0]
        spec = sfft.rfft(lat.astype(real, copy=False), n=n0, axis=0, workers=host_threads())
        out[:nh, y0:y0 + rows] = spec
        if not folded:
            out[nh:, y0:y0 + rows] = np.conj(spec[mirror])


def phi_spectrum(slab: Slab, shape, *, bin_width_s: float, pitch_m: float, n_dipoles,
                 periodic_xy: bool, square: bool, dtype, queue, folded: bool = False
                 ) -> tuple[RealFFT3, cla.Array]:
    """(FFT plan of the padded grid, F[Phi] -- or, ``square``, F[Phi * Phi] cut to lags
    0..nt-1 -- on it, whole or ``folded`` to the quarter
    :func:`clnlos.operators.spectral.folded_shape` keeps).

    Phi is taken over its temporal support only (:func:`~clnlos.diffusion.support_of`, all
    but SUPPORT_TOL of its energy; zero after) and transformed without a PSF table: its
    lateral DFT is analytic per time node (:func:`phi_lateral_factors`,
    :func:`confocal_lateral_factors`), so only the 1D transform along t remains (0.2 s
    instead of 0.8 s for a table and a 3D FFT at 1024 x 256 x 256). Both are integrated
    over the scan cells: a scan point collects the light of its whole cell, so the energy
    per scan point does not depend on the pitch (tested against a finer grid binned)."""
    q = get_queue(queue)
    dt = require_dtype(q.device, dtype)
    nt = int(shape[0])
    pad = _padded_grid(shape, periodic_xy)
    lags = support_of(lateral_integral_profile(slab, nt=nt, bin_width_s=bin_width_s, queue=q))
    plan = SlabTransmittance(slab, n_dipoles=n_dipoles, dtype=dt, queue=q)
    kw = dict(lags=lags, bin_width_s=bin_width_s, pitch_m=pitch_m, ny=pad[1], nx=pad[2])
    factors = (confocal_lateral_factors(plan, rows=min(nt, 2 * lags), **kw) if square
               else phi_lateral_factors(plan, **kw))
    fft = RealFFT3(pad, dt, q)
    spec = (cla.empty(q, folded_shape(fft.spec_shape), fft.cdtype) if folded
            else fft.empty_spectrum())
    with host_view(spec, write=True, read=False) as out:
        _write_phi_spectrum(out, factors)
    return fft, spec


def confocal_spectrum(slab: Slab, shape: tuple[int, int, int], *, bin_width_s: float,
                      pitch_m: float, n_dipoles: int | None = None, periodic_xy: bool = False,
                      dtype=np.float32, queue=None, cache=None) -> tuple[cla.Array, bool]:
    """(F[Phi * Phi] on the padded grid, whether it is stored folded -- always): the
    spectrum of :func:`confocal_psf`, built from its analytic lateral factors
    (:func:`confocal_lateral_factors`, zero at lags >= nt) and stored folded (a quarter:
    :func:`clnlos.operators.spectral.folded_shape`). ``cache``: a
    :class:`clnlos.runtime.spectrum_cache.SpectrumCache` to read the spectrum from, or store
    it in."""
    q = get_queue(queue)
    dt = require_dtype(q.device, dtype)
    key = None
    if cache is not None:
        key = cache.key("slab-confocal", slab=dataclasses.asdict(slab), n_dipoles=n_dipoles,
                        shape=[int(v) for v in shape], bin_width_s=float(bin_width_s),
                        pitch_m=float(pitch_m), periodic_xy=bool(periodic_xy),
                        dtype=dt.name, folded=True, cells="integrated")
        full = RealFFT3(_padded_grid(shape, periodic_xy), dt, q).spec_shape
        spec = cla.empty(q, folded_shape(full), COMPLEX_OF[dt])
        if cache.load(key, spec):
            return spec, True
    _, spec = phi_spectrum(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                           n_dipoles=n_dipoles, periodic_xy=periodic_xy, square=True,
                           dtype=dt, queue=q, folded=True)
    if cache is not None:
        cache.store(key, spec)
    return spec, True


def confocal_psf(slab: Slab, shape: tuple[int, int, int], *, bin_width_s: float,
                 pitch_m: float, n_dipoles: int | None = None, periodic_xy: bool = False,
                 dtype=np.float32, queue=None) -> cla.Array:
    """Phi * Phi on the padded grid (:func:`_padded_grid`: at least 2 nt, 2 ny, 2 nx) for
    transients of ``shape``.

    ``periodic_xy``: the grid is (2 nt, ny, nx), a convolution that wraps laterally -- for
    a forward model whose input already extends past the kept area by the blur's reach
    (:func:`lateral_reach_m`), where the wrapped border is cropped away.

    Phi * Phi[k, y, x] is the fraction of the light entering the slab at the origin that,
    after crossing it twice, leaves through the scan cell (y, x) in lag bin k (physical
    units: its sum approximates the squared total transmittance), over lags 0..nt-1 only --
    the only ones that reach the time window from inside it; built from
    :func:`confocal_lateral_factors` by :func:`phi_spectrum` and transformed back.
    """
    fft, spec = phi_spectrum(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                             n_dipoles=n_dipoles, periodic_xy=periodic_xy, square=True,
                             dtype=dtype, queue=queue)
    phi2 = fft.inverse(spec, cla.empty(fft.queue, fft.shape, fft.dtype))
    nt = int(shape[0])  # exactly zero past the window (the inverse FFT leaves round-off)
    fill_zero(phi2.queue, phi2,
              offset_bytes=nt * phi2.shape[1] * phi2.shape[2] * phi2.dtype.itemsize)
    return phi2


KERNELS = ("cdt", "eq8")  # hidden-face kernels: CDT's Phi * Phi, the far-target Eq. 8 one


def eq8_psf(slab: Slab, shape: tuple[int, int, int], *, bin_width_s: float, pitch_m: float,
            n_dipoles: int | None = None, periodic_xy: bool = False, dtype=np.float32,
            queue=None) -> np.ndarray:
    """The hidden-face kernel K that Eq. 8 gives for a target far from the face, on the grid
    and in the conventions of :func:`confocal_psf` (host array, shape of the padded grid).

    Eq. 8: tau(r0, t) = sum_{r1, r2} Phi(r1 - r0) (x)_t Phi(r2 - r0) (x)_t I(r1, r2, t). For a
    target at z >> |r1 - r2| (a few cm), |x - r1| + |x - r2| = 2 |x - m| + O(|r1 - r2|^2 / z)
    with m = (r1 + r2) / 2, and the cosines and distances are those of the confocal point
    m: I(r1, r2, t) = I_c(m, t). With r1 = m + delta / 2, r2 = m - delta / 2 (unit Jacobian)

        tau(r0, t) = sum_m K(m - r0, t) (x)_t I_c(m, t),
        K(u, t) = int d^2 delta Phi(u + delta / 2) (x)_t Phi(u - delta / 2)
                = 4 (Phi * Phi)(2 u, t)

    -- in space the product of the two legs at the two face points (integrated over their
    separation), in time their convolution. CDT's Phi * Phi instead puts the confocal point
    at r1 + r2 - r0. Phi(rho, t) = T(0, t) exp(-rho^2 / (4 D v t)), and in the time
    convolution the two legs' Gaussian widths add up to that of the total lag (4 D v t1 +
    4 D v t2 = 4 D v t), so (Phi * Phi)(u, t) = P2(t) exp(-u^2 / (4 D v t)) / (4 pi D v t)
    with P2 the laterally integrated P * P, and

        K(u, t) = P2(t) exp(-u^2 / (D v t)) / (pi D v t):

    the same energy per lag as CDT's kernel, half its lateral width (standard deviation
    sqrt(D v t / 2) per axis against sqrt(2 D v t)). Built here as the lateral sum of
    :func:`confocal_psf` per lag (the exact P2 on this grid, bin-averaged as it is) times
    the cell-averaged Gaussian of that width at the lag's centre k dt, normalised to unit
    lateral sum (a narrow kernel keeps its energy when it is narrower than a cell).
    """
    phi2 = confocal_psf(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                        n_dipoles=n_dipoles, periodic_xy=periodic_xy, dtype=dtype,
                        queue=queue).get().astype(np.float64)
    energy = phi2.sum(axis=(1, 2))
    b = slab.D * slab.v * np.arange(phi2.shape[0]) * float(bin_width_s)  # D v t, m^2

    def cells(n: int) -> np.ndarray:
        g = cell_gaussian(grid_offsets(n, pitch_m), np.maximum(b, 1e-300), pitch_m)
        return g / g.sum(axis=1, keepdims=True)

    gy, gx = cells(phi2.shape[1]), cells(phi2.shape[2])
    return (energy[:, None, None] * gy[:, :, None] * gx[:, None, :]).astype(phi2.dtype)


def check_kernel(kernel: str) -> str:
    """The hidden-face kernel name, checked against KERNELS."""
    if kernel not in KERNELS:
        raise ParameterError("kernel", kernel, " or ".join(repr(k) for k in KERNELS))
    return kernel


def autoconvolution_full(p: np.ndarray) -> np.ndarray:
    """p * p, the full linear 2D convolution of a real array with itself (shape 2 n - 1 per
    axis), by real FFTs on a zero-padded 2-3-5-smooth grid (what scipy.signal.fftconvolve
    computes, without importing scipy.signal: 1.3 s of the CLI's start)."""
    full = tuple(2 * s - 1 for s in p.shape)
    fast = tuple(sfft.next_fast_len(s, real=True) for s in full)
    spec = sfft.rfftn(p, fast)
    out = sfft.irfftn(spec * spec, fast)
    return out[tuple(slice(0, s) for s in full)]


def lateral_reach_m(slab: Slab, *, window_s: float, tol: float = 1e-3,
                    n_dipoles: int | None = None, queue=None) -> float:
    """Radius R (m) outside which the confocal blur holds less than ``tol`` of its energy.

    With P(rho) = integral of Phi(t, rho) over lags 0..window_s (the light that can reach the
    time window), the confocal blur integrated over time is about P * P (2D convolution);
    R is the smallest offset with sum_{|rho| > R} (P * P) < tol * sum (P * P). The profile is
    computed on a grid of 256 cells per side reaching 20 (d + 2 z_e), a bound well past the
    lateral decay length (d + 2 z_e) / pi of the slab's diffuse spot, whatever the scan
    pitch (a coarse scan grid would sample the blur too sparsely to see its reach).
    """
    r_max = 20.0 * (slab.thickness_m + 2.0 * slab.ze)
    pitch = 2.0 * r_max / 256
    n = 2 * int(math.ceil(r_max / pitch))
    nt = 64
    q = get_queue(queue)
    phi = diffusion_psf(slab, nt=nt, bin_width_s=window_s / nt, ny=n, nx=n, pitch_m=pitch,
                        n_dipoles=n_dipoles, dtype=np.float64 if has_fp64(q.device) else
                        np.float32, queue=q)
    p = np.fft.fftshift(phi.astype(np.float64).sum(axis=0))  # centre (zero offset) at n/2
    pp = autoconvolution_full(p)  # zero offset at index n
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
              queue=None, scratch=None, cache=None, kernel: str = "cdt") -> SpectralFilter:
    """The confocal blur as an operator on transients of ``shape`` [t, y, x].

    ``mode="convolve"``: the forward model tau = (Phi * Phi) * I in physical units (the DC
    gain is the squared slab transmittance). ``mode="wiener"``: the deconvolution
    conj(H)/(|H|^2 + 1/SNR) with H normalised to unit DC gain. ``scratch``: work buffers
    shared with a plan's other stages (:class:`clnlos.runtime.buffers.Scratch`); ``cache``: an
    on-disk :class:`clnlos.runtime.spectrum_cache.SpectrumCache` for the spectrum. ``kernel``:
    ``"cdt"`` (Phi * Phi, :func:`confocal_psf`) or ``"eq8"`` (:func:`eq8_psf`, not cached).
    """
    if check_kernel(kernel) == "eq8":
        psf = eq8_psf(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                      n_dipoles=n_dipoles, periodic_xy=periodic_xy, dtype=dtype, queue=queue)
        return SpectralFilter(psf, shape, mode=mode, snr=snr, normalize=(mode == "wiener"),
                              lateral_pad=lateral_pad, dtype=dtype, queue=queue,
                              scratch=scratch)
    spec, folded = confocal_spectrum(slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m,
                                     n_dipoles=n_dipoles, periodic_xy=periodic_xy,
                                     dtype=dtype, queue=queue, cache=cache)
    return SpectralFilter(_padded_grid(shape, periodic_xy), shape, mode=mode, snr=snr,
                          normalize=(mode == "wiener"), lateral_pad=lateral_pad, dtype=dtype,
                          queue=queue, spectrum=spec, spectrum_folded=folded, scratch=scratch)


# The slab blur's time scales, from the laterally integrated profile P of Phi: the confocal
# blur integrated over the plane is P * P (lateral integration commutes with the convolution).
BLUR_REACH_TOL = 1e-3  # the blur's reach: all but this fraction of the energy of P * P


@dataclasses.dataclass(frozen=True)
class BlurTimeScales:
    """Time scales of the confocal slab blur Phi * Phi, in bins of ``bin_width_s``.

    ``peak_lags``: the lag of its maximum (an arrival at t is seen at its brightest at
    t + peak * dt); ``reach_lags``: the lag by which all but BLUR_REACH_TOL of its energy
    has arrived (light entering the time window at t leaves the slab by t + reach * dt)."""

    peak_lags: int
    reach_lags: int


def blur_time_scales(slab: Slab, *, bin_width_s: float, tol: float = BLUR_REACH_TOL,
                     queue=None) -> BlurTimeScales:
    """:class:`BlurTimeScales` of ``slab`` at ``bin_width_s`` (s), from P * P with P the
    laterally integrated transmittance (:func:`~clnlos.diffusion.lateral_integral_profile`)
    on a grid long enough to hold all but SUPPORT_TOL of P."""
    nt = 256
    while True:
        prof = lateral_integral_profile(slab, nt=nt, bin_width_s=bin_width_s, queue=queue)
        if support_of(prof) < nt or nt >= 1 << 16:
            break
        nt *= 4
    p2 = np.convolve(prof, prof)
    arrived = np.cumsum(p2) / p2.sum()
    return BlurTimeScales(peak_lags=int(np.argmax(p2)),
                          reach_lags=int(np.argmax(arrived >= 1.0 - tol)) + 1)






@lru_cache(maxsize=16)
def blur_margin(slab, window_s, pitch_m, points, tol, n_dipoles, queue) -> tuple[int, bool]:
    """(cells per side to add so the scan grid covers the blur's reach, rounded to a
    2-3-5-smooth size; whether that covers all of it). The margin is capped at twice the
    scan; a capped margin needs a non-wrapping (zero-padded) lateral convolution."""
    reach = lateral_reach_m(slab, window_s=window_s, tol=tol,
                            n_dipoles=n_dipoles, queue=queue)
    need = int(math.ceil(reach / pitch_m - 1e-9))
    m = min(need, 2 * points)
    while sfft.next_fast_len(points + 2 * m, real=True) != points + 2 * m:
        m += 1
    return m, m >= need


CACHES.register("blur margins", blur_margin.cache_clear)


def forward_blur(slab, shape, bin_width_s, pitch_m, n_dipoles, periodic, dtype_str, queue):
    """The physical Phi * Phi operator, shared by every scene of one geometry (a study;
    cached in :data:`clnlos.runtime.caches.FORWARD_BLURS`).

    ``periodic``: the input carries the blur's reach as a margin that is cropped after the
    blur, so the lateral convolution may wrap (no lateral padding: 4x fewer FFT cells).
    """
    key = (slab, shape, bin_width_s, pitch_m, n_dipoles, periodic, dtype_str, queue)
    return FORWARD_BLURS.get(key, lambda: slab_blur(
        slab, shape, bin_width_s=bin_width_s, pitch_m=pitch_m, mode="convolve",
        n_dipoles=n_dipoles, periodic_xy=periodic, dtype=np.dtype(dtype_str), queue=queue),
        queue)

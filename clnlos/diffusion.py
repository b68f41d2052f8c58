"""Slab diffusion: time-resolved diffuse transmittance through a homogeneous slab.

Physics (Patterson, Chance & Wilson 1989; Contini, Martelli & Zaccanti 1997), flux
(Fick's law) form for a pencil beam, per unit injected energy, units 1/(m^2 s)::

    T(rho, t) = (4 pi D v)^(-3/2) t^(-5/2) exp(-mu_a v t - rho^2 / (4 D v t))
                * 1/2 * sum_{m=-M..M} [ z1_m exp(-z1_m^2/(4Dvt)) - z2_m exp(-z2_m^2/(4Dvt)) ]
    z1_m = (1-2m) d - 4m ze - z0,   z2_m = (1-2m) d - (4m-2) ze + z0
    D = 1/(3 (mu_a + mu_s')),  z0 = 1/mu_s',  v = c0/n,
    ze = 2 D (1 + R_eff)/(1 - R_eff)

with R_eff the effective internal reflection from the Fresnel integrals for relative index
n (medium / outside). ``n_dipoles = M`` means 2M+1 image pairs ``m = -M..M``.

The computation runs in the OpenCL kernel ``kernels/diffusion.cl`` (log space, paired
image terms, an eigenmode series at late times in "auto" mode); see its header.

Left out: anisotropic scattering beyond the reduced coefficient, refractive-index mismatch
at the entrance other than through ze, finite beam size (pencil beam), time-dependent
detector response (added by the forward model when a scene asks for it).
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla

from clnlos.checks import positive
from clnlos.errors import ParameterError
from clnlos.physics.grid import grid_offsets
from clnlos.physics.slab import Slab, effective_reflection  # noqa: F401 (re-exported)
from clnlos.runtime.buffers import kernel_int, round_up
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.programs import get_kernels, real_defines

# Energy fraction of the slab response left out where it is truncated to its support.
SUPPORT_TOL = 1e-7
# ln(1/tolerance) of the auto mode: terms below tol relative to the largest are dropped.
LN_TOL = {np.dtype(np.float32): math.log(1e8), np.dtype(np.float64): math.log(1e17)}


def _check_n_dipoles(n_dipoles) -> int:
    if n_dipoles is None:
        return -1
    if isinstance(n_dipoles, bool) or int(n_dipoles) != n_dipoles or n_dipoles < 0:
        raise ParameterError("n_dipoles", n_dipoles, "None (auto) or an integer >= 0")
    if n_dipoles > 100_000:
        raise ParameterError("n_dipoles", n_dipoles, "<= 100000")
    return int(n_dipoles)


class SlabTransmittance:
    """Plan: evaluates T(rho, t) of one slab on one queue in one precision.

    Parameters
    ----------
    slab : Slab
    n_dipoles : int or None
        M (2M+1 image pairs), or None for the auto mode (relative truncation error below
        1e-8 in float32, 1e-17 in float64 at every sample).
    dtype : float32 or float64
    queue : pyopencl.CommandQueue, device spec string or None
    """

    def __init__(self, slab: Slab, *, n_dipoles: int | None = None, dtype=np.float32,
                 queue=None):
        self.slab = slab
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.n_dipoles = _check_n_dipoles(n_dipoles)
        self.kernels = get_kernels(self.queue, "diffusion", real_defines(self.dtype))
        r = self.dtype.type
        s = slab
        self._params = (r(s.D * s.v), r(s.mu_a * s.v), r(s.thickness_m), r(s.z0), r(s.ze),
                        np.int32(self.n_dipoles), r(LN_TOL[self.dtype]))

    def pairs_device(self, rho_g: cla.Array, t_g: cla.Array, out_g: cla.Array | None = None
                     ) -> cla.Array:
        """Element-wise T(rho_g[i], t_g[i]) on the device (1D arrays of ``self.dtype``)."""
        n = rho_g.size
        if out_g is None:
            out_g = cla.empty(self.queue, n, self.dtype)
        if n:
            self.kernels.transmittance_pairs(
                self.queue, (round_up(n, 64),), None, rho_g.data, t_g.data, out_g.data,
                kernel_int(n, "samples"), *self._params)
        return out_g

    def outer_device(self, rho_g: cla.Array, t_g: cla.Array, scale: float = 1.0,
                     out_g: cla.Array | None = None) -> cla.Array:
        """Table ``out[it, ir] = scale * T(rho[ir], t[it])`` on the device (written into
        ``out_g``, a contiguous (nt, nr) array, when given)."""
        nr, nt = rho_g.size, t_g.size
        if out_g is None:
            out_g = cla.empty(self.queue, (nt, nr), self.dtype)
        if nr and nt:
            log_t0 = self.log_series_device(t_g)
            self.kernels.transmittance_outer(
                self.queue, (round_up(nr, 16), round_up(nt, 4)), None, rho_g.data, t_g.data,
                log_t0.data, out_g.data, kernel_int(nr, "radii"), kernel_int(nt, "time bins"),
                self._params[0],
                self.dtype.type(scale))
        return out_g

    def log_series(self, t_s: np.ndarray) -> np.ndarray:
        """log T(0, t) at the times ``t_s`` (host float64 from the kernel's precision; -inf
        where T is 0): with it T(rho, t) = exp(log T(0, t) - rho^2 / (4 D v t))."""
        t = np.ascontiguousarray(np.asarray(t_s, np.float64).ravel(), self.dtype)
        if not t.size:
            return np.zeros(np.shape(t_s))
        log_t0 = self.log_series_device(cla.to_device(self.queue, t))
        return log_t0.get().astype(np.float64).reshape(np.shape(t_s))

    def log_series_device(self, t_g: cla.Array) -> cla.Array:
        """log T(0, t) for the times of the device array ``t_g`` (the series once per time
        sample, ``kernels/diffusion.cl`` log_series), on the device."""
        out_g = cla.empty(self.queue, t_g.size, self.dtype)
        if t_g.size:
            self.kernels.log_series(self.queue, (round_up(t_g.size, 64),), None, t_g.data,
                                    out_g.data, kernel_int(t_g.size, "time samples"),
                                    *self._params)
        return out_g

    def outer_avg_device(self, rho_g: cla.Array, t_nodes: np.ndarray, weights: np.ndarray,
                         scale: float, out_g: cla.Array) -> cla.Array:
        """``out[it, ir] = scale * sum_k weights[k] T(rho[ir], t_nodes[it, k])`` on the device
        (one pass: the node sum stays in registers); ``out_g`` contiguous (n_t, n_rho)."""
        n_t, n_nodes = t_nodes.shape
        nr = rho_g.size
        if not (nr and n_t):
            return out_g
        t_g = cla.to_device(self.queue, np.ascontiguousarray(t_nodes, self.dtype).ravel())
        w_g = cla.to_device(self.queue, np.asarray(weights, self.dtype))
        log_t0 = self.log_series_device(t_g)
        self.kernels.transmittance_outer_avg(
            self.queue, (round_up(nr, 16), round_up(n_t, 4)), None, rho_g.data, t_g.data,
            log_t0.data, w_g.data, out_g.data, kernel_int(nr, "radii"),
            kernel_int(n_t, "time bins"), kernel_int(n_nodes, "time nodes"), self._params[0],
            self.dtype.type(scale))
        return out_g

    def __call__(self, rho_m, t_s) -> np.ndarray:
        rho = np.asarray(rho_m, dtype=np.float64)
        t = np.asarray(t_s, dtype=np.float64)
        if np.isnan(rho).any() or np.isinf(rho).any():
            raise ParameterError("rho_m", "NaN/Inf in array", "finite distances in m")
        if np.isnan(t).any() or np.isinf(t).any():
            raise ParameterError("t_s", "NaN/Inf in array", "finite times in s")
        rho_b, t_b = np.broadcast_arrays(rho, t)
        shape = rho_b.shape
        if rho_b.size == 0:
            return np.zeros(shape, self.dtype)
        rho_g = cla.to_device(self.queue, np.ascontiguousarray(rho_b.ravel(), self.dtype))
        t_g = cla.to_device(self.queue, np.ascontiguousarray(t_b.ravel(), self.dtype))
        return self.pairs_device(rho_g, t_g).get().reshape(shape)


def slab_transmittance(rho_m, t_s, *, thickness_m, mu_a, mu_s_prime, n, ze_m=None,
                       n_dipoles=None, dtype=np.float32, device=None) -> np.ndarray:
    """Diffuse transmittance T(rho, t) of a slab, 1/(m^2 s), computed by the OpenCL kernel.

    ``rho_m`` (lateral distance from the entry point, m) broadcasts against ``t_s`` (time
    since injection, s). ``t <= 0`` gives 0. ``n_dipoles=None`` picks the series length per
    sample for a relative truncation error below 1e-8 (float32) / 1e-17 (float64);
    an integer M sums exactly the 2M+1 image pairs m = -M..M (values where truncation would
    make the sum negative are clamped at 0). ``device``: spec string, queue or None.
    """
    slab = Slab(thickness_m=thickness_m, mu_a=mu_a, mu_s_prime=mu_s_prime, n=n, ze_m=ze_m)
    return SlabTransmittance(slab, n_dipoles=n_dipoles, dtype=dtype, queue=device)(rho_m, t_s)


def diffusion_psf(slab: Slab, *, nt: int, bin_width_s: float, ny: int, nx: int,
                  pitch_m: float, n_dipoles: int | None = None, dtype=np.float32,
                  queue=None, normalize: str = "physical", time_nodes: int = 4) -> np.ndarray:
    """The slab blur Phi(t, y, x) on an FFT grid, shape (nt, ny, nx), axes [t, y, x].

    Convention (stated once, used everywhere): ``Phi[k, j, i]`` is the response averaged
    over the lag bin centred on ``k * bin_width_s``, i.e. over [(k - 1/2) dt, (k + 1/2) dt]
    (k = 0..nt-1, causal; ``time_nodes`` Gauss-Legendre nodes per bin, 1 = point sample at
    the lag), at lateral offset ``(grid_offsets(ny)[j], grid_offsets(nx)[i])`` -- zero lag
    and zero offset at index [0, 0, 0], wrap order, no half-pixel shift. So a convolution
    by FFT moves a delta at (t0, y0, x0) to (t0 + lag, y0, x0). Averaging over the bin
    matters on coarse bins, where the sharp rise of Phi would otherwise shift its centroid.

    normalize: ``"physical"`` -- ``T * dt * dx * dy`` (probability that a photon entering at
    the origin leaves in that cell and bin; the sum approximates the slab's total
    transmittance); ``"sum"`` -- unit sum; ``"none"`` -- T in 1/(m^2 s).
    """
    if normalize not in ("physical", "sum", "none"):
        raise ParameterError("normalize", normalize, "'physical', 'sum' or 'none'")
    for name, val in (("nt", nt), ("ny", ny), ("nx", nx)):
        if int(val) != val or val < 1:
            raise ParameterError(name, val, "an integer >= 1")
    dt = positive("bin_width_s", bin_width_s)
    pitch = positive("pitch_m", pitch_m)
    if int(time_nodes) != time_nodes or not 1 <= time_nodes <= 32:
        raise ParameterError("time_nodes", time_nodes, "an integer from 1 to 32")
    plan = SlabTransmittance(slab, n_dipoles=n_dipoles, dtype=dtype, queue=queue)
    psf = diffusion_psf_device(plan, nt=nt, bin_width_s=dt, ny=ny, nx=nx, pitch_m=pitch,
                               physical=normalize == "physical", time_nodes=time_nodes).get()
    if normalize == "sum":
        total = psf.sum(dtype=np.float64)
        if total > 0:
            psf = (psf / total).astype(plan.dtype)
    return psf


def diffusion_psf_device(plan: SlabTransmittance, *, nt: int, bin_width_s: float, ny: int,
                         nx: int, pitch_m: float, physical: bool = True, time_nodes: int = 4,
                         lags: int | None = None, out_g: cla.Array | None = None) -> cla.Array:
    """:func:`diffusion_psf` computed and kept on the device (no host round trip).

    Only lags 0..``lags``-1 are evaluated (default: all ``nt``); the rest of ``out_g`` (a
    contiguous (>= lags, ny, nx) device array, allocated when not given) is left untouched,
    so a caller that zeroed it gets the PSF truncated to its support
    (:func:`temporal_support_lags`). The time nodes are summed inside the kernel in the
    plan's precision (Gauss-Legendre weights are positive and sum to 1: no cancellation).
    """
    q, dtype = plan.queue, plan.dtype
    lags = nt if lags is None else int(lags)
    if out_g is None:
        out_g = cla.empty(q, (nt, ny, nx), dtype)
    if lags == 0:
        return out_g
    yo, xo = grid_offsets(ny, pitch_m), grid_offsets(nx, pitch_m)
    rho_g = cla.to_device(q, np.sqrt(yo[:, None] ** 2 + xo[None, :] ** 2).ravel().astype(dtype))
    t_nodes, w = bin_time_nodes(lags, bin_width_s, time_nodes)
    scale = bin_width_s * pitch_m * pitch_m if physical else 1.0
    plan.outer_avg_device(rho_g, t_nodes, w, scale, out_g=out_g[:lags].reshape(lags, ny * nx))
    return out_g


def bin_time_nodes(lags: int, bin_width_s: float, time_nodes: int = 4
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(t [lag, node] in s, weights [node] summing to 1): Gauss-Legendre nodes averaging a
    response over each lag bin [(k - 1/2) dt, (k + 1/2) dt] (:func:`diffusion_psf`'s
    convention; 1 node = the point sample at k dt)."""
    if time_nodes == 1:
        u, w = np.zeros(1), np.ones(1)
    else:
        u, w = np.polynomial.legendre.leggauss(int(time_nodes))
        u, w = u / 2, w / 2  # nodes in (-1/2, 1/2) of a bin, weights summing to 1
    return (np.arange(int(lags))[:, None] + u[None, :]) * float(bin_width_s), w


def lateral_integral_profile(slab: Slab, *, nt: int, bin_width_s: float,
                             queue=None) -> np.ndarray:
    """The slab response integrated over the lateral plane at lags (k + 1/2) dt, k < nt (1/s).

    Integrating the Gaussian exp(-rho^2 / (4 D v t)) over the plane gives 4 pi D v t, so the
    integral is 4 pi D v t T(0, t); float64 on the host from the float32 kernel."""
    t = (np.arange(nt) + 0.5) * float(bin_width_s)
    plan = SlabTransmittance(slab, dtype=np.float32, queue=queue)
    return 4 * np.pi * slab.D * slab.v * t * plan(np.zeros(nt), t).astype(np.float64)


def temporal_support_lags(slab: Slab, *, nt: int, bin_width_s: float,
                          tol: float = SUPPORT_TOL, queue=None) -> int:
    """Lags (<= nt) that hold all but ``tol`` of the slab's laterally integrated response
    (:func:`lateral_integral_profile`): the support ends at the first lag after which the
    remaining energy is below ``tol`` of the total. Used to evaluate the slab PSF only where
    it is not negligible (about 5 ns for the CDT slab at tol = 1e-7, against windows of
    8-20 ns)."""
    prof = lateral_integral_profile(slab, nt=nt, bin_width_s=bin_width_s, queue=queue)
    return support_of(prof, tol)


def support_of(prof: np.ndarray, tol: float = SUPPORT_TOL) -> int:
    """Length of the leading part of a non-negative profile holding all but ``tol`` of it."""
    total = prof.sum()
    if not np.isfinite(total) or total <= 0:
        return len(prof)
    tail = np.cumsum(prof[::-1])[::-1] / total  # energy at lags >= k
    beyond = np.nonzero(tail < tol)[0]
    return int(min(len(prof), beyond[0] + 1)) if beyond.size else len(prof)


__all__ = ["Slab", "SlabTransmittance", "slab_transmittance", "diffusion_psf",
           "diffusion_psf_device", "temporal_support_lags", "lateral_integral_profile",
           "support_of", "SUPPORT_TOL",
           "effective_reflection", "grid_offsets"]

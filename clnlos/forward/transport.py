"""Confocal light-cone transport as a linear operator: albedo volume -> hidden-side transient.

The physics of ``clnlos simulate`` (:mod:`clnlos.forward.model`, ``kernels/lightcone.cl``) for a
volume of Lambertian voxels facing the scan plane: a voxel at depth z with albedo-weighted
coverage rho (albedo x fraction of the voxel's lateral cell covered, dimensionless) sends to
the scan point at distance r

    I(t, s) += rho * p^2 * f_r cos^2(theta_relay) cos^2(theta_obj) / r^4
             = rho * p^2 * z^4 / (pi r^8)          at t = 2 r / c        (1/(m^2 sr) per bin)

(p the lateral pitch, cos = z / r for both angles, f_r = 1/pi). With u = z^2 and v = r^2 the
sum over voxels is a 3D convolution in (v, y, x) with the light cone h(v, y, x) =
delta(v - x^2 - y^2) (O'Toole et al. 2018), so the operator is

    I = W_t R_{v->t} (h * R_{z->u} W_z rho)

with mass-conserving bin-overlap resamplings R (``kernels/resample.cl``), W_z = p^2 z^4 / pi
(times an optional ``depth_weight``), W_t = r^-8 at the bin centres (r^-(4 + p) for a
voxel of radial falloff 1/r^p, ``falloff``; 4 Lambertian), and the convolution on a
zero-padded FFT grid (``kernels/wiener.cl``; no wrap-around). The light cone is splatted
linearly between v bins, each lateral offset carrying unit weight.

Grids: volume [z, y, x] with depth bin k spanning [k, k+1) c dt / 2 (the reconstruction
volume); transient [t, y', x'] with bin k spanning [k, k+1) dt, on the scan grid widened by
``margin`` cells per side (for a slab blur that reaches past the scan border). Voxels
shallower than ``depth_min_m`` are outside the support (zero columns) and transient rows
that only such voxels reach are exactly zero, which also keeps the r^-8 weight's range
(and float32 round-off) bounded.

A reflectance lobe (``lobe``, a retro slice :class:`clnlos.physics.lobe.RetroLobe`): each
voxel's weight is multiplied by G(d, z) of :mod:`clnlos.physics.lobe` (its BRDF's retro
slice averaged over its cell and, behind a slab, over the slab's footprint), written as K
separable terms sum_k a_k(z) b_k(d), the depth weights a_k taken on the u grid (at the
depth sqrt(u) of each u bin's centre). Each term is a light cone with the volume weight a_k
and the lateral kernel weight b_k, and the terms share the data side:

    I = W_t R_{v->t} sum_k (h_k * a_k R_{z->u} W_z rho),   h_k(v, d) = b_k(d) h(v, d)

(K = 1, a = b = 1: exactly the Lambertian operator). a_k acts on the u axis alone, so it
commutes with the FFT over (y, x): with the host FFT (``RealFFT3.split_axes``) the volume is
transformed over (y, x) once, and each term costs a transform along t and two element-wise
passes; the adjoint likewise (the data's forward FFT once, per term a product and an inverse
along t, one inverse over (y, x)). Elsewhere (VkFFT) each term is its own 3D transform of
a_k R_{z->u} W_z rho. Left out: occlusion, surface orientation other than facing the scan
plane, interreflections.
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla
import scipy.fft as sfft
import scipy.sparse as sp

from clnlos.physics.constants import C0
from clnlos.errors import ParameterError
from clnlos.operators.base import LinearOperator
from clnlos.operators.resample import AxisResample, overlap_matrix
from clnlos.operators.spectral import (
    fold_spectrum,
    multiply_spectrum,
    multiply_spectrum_into,
    scale_rows,
)
from clnlos.physics.lightcone import lightcone_psf_grid
from clnlos.physics.lobe import RetroLobe, SeparableLobe, lobe_weight_table, separable_terms
from clnlos.runtime.blas import single_threaded_blas
from clnlos.runtime.buffers import Scratch, fill_zero
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.fft import RealFFT3
from clnlos.runtime.programs import get_kernels, real_defines


def signed_offsets(n: int, shift: int = 0) -> np.ndarray:
    """Lateral offset (cells) that index j of an n-cell FFT grid stands for when the kernel is
    stored shifted by ``shift`` cells: h'[j] = h[(j - shift) mod n], offsets in [-n/2, n/2)."""
    j = (np.arange(n) - int(shift)) % n
    return np.where(j < (n + 1) // 2, j, j - n)


def lightcone_kernel(nv: int, pad_t: int, py: int, px: int, *, dv_m2: float, pitch_m: float,
                     shift: int = 0, lateral_weight: np.ndarray | None = None) -> np.ndarray:
    """Light cone on a (pad_t, py, px) grid (float64): for each lateral offset d (cells) the
    v-shift s = |d|^2 p^2 / dv in bins, split linearly between bins floor(s) and floor(s)+1,
    weight ``lateral_weight[|dy|, |dx|]`` per offset (default 1). Shifts that cannot reach v
    bins 0..nv-1 from inside, or that would wrap around the padded time axis, are dropped."""
    iy, ix = signed_offsets(py, shift), signed_offsets(px, shift)
    s = ((iy[:, None] * pitch_m) ** 2 + (ix[None, :] * pitch_m) ** 2) / dv_m2
    w = None if lateral_weight is None else \
        lateral_weight[np.abs(iy)[:, None], np.abs(ix)[None, :]]
    return lightcone_psf_grid(s, pad_t, min(nv - 1, pad_t - nv), w)


def lobe_offsets(pad_shape) -> tuple[int, int]:
    """Lateral offsets (|dy|, |dx| = 0 .. n - 1 cells) a padded grid's light cone reaches."""
    return pad_shape[1] // 2 + 1, pad_shape[2] // 2 + 1

LAMBERTIAN_FALLOFF = 4.0  # the radial falloff 1/r^p of a Lambertian voxel (W_t = r^-8)
LOBE_SLOT = "lobe"  # scratch slot of the summed spectrum (forward) or the data's (adjoint)
LATERAL_SLOT = "lobe lateral"  # the volume's (y, x) spectrum on the u rows (split terms)


class LightConeTransport(LinearOperator):
    """Plan: rho [nz, ny, nx] -> I [nt, ny + 2 margin, nx + 2 margin] (see module docstring).

    Parameters
    ----------
    shape : (nt, ny, nx)
        Time bins (= depth bins) and scan points; the scan is square cells of
        ``scan_width_m / nx``.
    bin_width_s : float
        Transient bin width dt (s); depth bins are c dt / 2.
    scan_width_m : float
        Side of the scanned area (m), points at cell centres.
    margin : int
        Cells added per side of the output grid.
    depth_min_m : float
        Shallowest depth of the volume's support (m).
    depth_weight : array (nz,) or None
        Extra factor per depth bin on the input (a column scaling for solvers).
    scratch : :class:`clnlos.runtime.buffers.Scratch`, optional
        Work buffers shared with a plan's other stages (a private one by default).
    lobe : :class:`clnlos.physics.lobe.RetroLobe`, optional
        The voxels' retro slice (default Lambertian, 1/pi).
    footprint_rms_m : float
        rms radius (m) of the slab's footprint that widens the lobe (0: no slab).
    lobe_terms : int, optional
        Separable terms K of the lobe (default: the fewest within ``lobe_tolerance``);
        ``self.lobe`` records them and their error.
    lobe_tolerance : float, optional
        Weighted relative error the default K stops at (default the lobe's own,
        :data:`clnlos.physics.lobe.LOBE_TOLERANCE` or a retroreflector's).
    falloff : float
        Radiometric exponent p of the voxels' radial falloff: W_t = r^-(4 + p), the
        Lambertian 1/r^4 at p = 4 (default); p = 2 a retroreflector whose returned cone the
        scanned spot holds (:mod:`clnlos.physics.retroreflector` Eq. 3, S ~ r^2: the
        published (t/T)^2 weighting of O'Toole et al. 2018), the cosines kept.
    """

    name = "lightcone_transport"

    def __init__(self, shape, *, bin_width_s: float, scan_width_m: float, margin: int = 0,
                 depth_min_m: float = 0.0, depth_weight=None, dtype=np.float32, queue=None,
                 scratch: Scratch | None = None, lobe: RetroLobe | None = None,
                 footprint_rms_m: float = 0.0, lobe_terms: int | None = None,
                 falloff: float = LAMBERTIAN_FALLOFF, lobe_tolerance: float | None = None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        nt, ny, nx = (int(v) for v in shape)
        if min(nt, ny, nx) < 1 or margin < 0:
            raise ParameterError("shape", shape, "three sizes >= 1 (and margin >= 0)")
        self.margin = m = int(margin)
        self.bin_width_s, self.scan_width_m = float(bin_width_s), float(scan_width_m)
        self.pitch_m = pitch = self.scan_width_m / nx
        dz = C0 * self.bin_width_s / 2
        R = nt * dz
        self.depth_m = (np.arange(nt) + 0.5) * dz
        self.k_min = k_min = min(nt - 1, max(0, int(math.floor(depth_min_m / dz + 1e-9))))
        dv = R * R / nt
        j0 = int(math.floor((k_min * dz) ** 2 / dv + 1e-9))  # first v (and u) bin used
        nv = nt - j0
        self.in_shape = (nt, ny, nx)
        self.out_shape = (nt, ny + 2 * m, nx + 2 * m)
        # z -> u with weights, written into the padded FFT grid (rows 0..nv-1 = bins j0..)
        z_edges = np.arange(nt + 1) * dz
        v_edges = np.sqrt(j0 * dv + np.arange(nv + 1) * dv)  # v-bin edges as distances r
        w_z = pitch * pitch * self.depth_m**4 / math.pi
        if depth_weight is not None:
            w_z = w_z * np.asarray(depth_weight, np.float64)
        w_z[:k_min] = 0.0
        to_u = overlap_matrix(z_edges**2, v_edges**2)
        w_t = np.zeros(nt)
        self.falloff = float(falloff)
        w_t[k_min:] = self.depth_m[k_min:] ** -(4.0 + self.falloff)
        to_t = (sp.diags(w_t) @ overlap_matrix(v_edges**2, z_edges**2)).tocsr()
        # grid: lateral offsets up to (n - 1 + m) either way; time up to the largest shift
        py = sfft.next_fast_len(2 * ny + 2 * m - 1, real=True)
        px = sfft.next_fast_len(2 * nx + 2 * m - 1, real=True)
        q_max = ((ny - 1 + m) ** 2 + (nx - 1 + m) ** 2) * pitch * pitch
        s_max = min(nv, int(math.ceil(q_max / dv)) + 2)
        pad_t = sfft.next_fast_len(nv + s_max, real=True)
        self.pad_shape = (pad_t, py, px)
        self.nv = nv
        self.u_depth_m = np.sqrt((j0 + np.arange(nv) + 0.5) * dv)  # u bins' centre depths
        self._u_edges_m = v_edges  # ... and their edges, as depths sqrt(u)
        self.fft = RealFFT3(self.pad_shape, self.dtype, self.queue)
        with single_threaded_blas():  # its SVDs beside PoCL's and the FFT's threads
            self.lobe = self._separable_lobe(lobe, footprint_rms_m, lobe_terms, lobe_tolerance)
        K = self.lobe.terms
        # the terms split over the axes (module docstring) where the FFT allows it
        self.split = K > 1 and self.fft.split_axes
        to_u_w = (to_u @ sp.diags(w_z)).tocsr()
        weights = [None] if self.split else list(self.lobe.a)  # a_k into each R_{z->u}
        self._pre = [AxisResample(to_u_w if a is None else (sp.diags(a) @ to_u_w).tocsr(),
                                  (ny, nx), out_plane=(py, px), out_rows=pad_t,
                                  dtype=self.dtype, queue=self.queue) for a in weights]
        self._alpha = ([cla.to_device(self.queue, a.astype(self.dtype)) for a in self.lobe.a]
                       if self.split else None)
        to_t_pad = sp.hstack([to_t, sp.csr_matrix((nt, pad_t - nv))]).tocsr()
        self._post = AxisResample(to_t_pad, self.out_shape[1:], in_plane=(py, px),
                                  dtype=self.dtype, queue=self.queue)
        # the cones are real and even in y and x unless shifted by a margin: stored folded
        self.folded = m == 0
        self.H = [self._spectrum(lightcone_kernel(
            nv, pad_t, py, px, dv_m2=dv, pitch_m=pitch, shift=m,
            lateral_weight=b).astype(self.dtype)) for b in self.lobe.b]
        self.scratch = Scratch(self.queue) if scratch is None else scratch
        self.scratch.reserve("a", self.pad_shape, self.dtype)
        self.scratch.reserve("b", self.fft.spec_shape, self.fft.cdtype)
        if K > 1:
            self.scratch.reserve(LOBE_SLOT, self.fft.spec_shape, self.fft.cdtype)
        if self.split:
            self.scratch.reserve(LATERAL_SLOT, (nv,) + self.fft.spec_shape[1:],
                                 self.fft.cdtype)
        self._k = get_kernels(self.queue, "wiener", real_defines(self.dtype))
        # blocks of the padded grid that hold data: what the model writes and reads
        self._in_block = (nv, ny, nx)
        self._out_block = (nv,) + self.out_shape[1:]

    def _spectrum(self, kernel: np.ndarray) -> cla.Array:
        """The half spectrum of a cone on the padded grid, folded where it is even
        (:func:`clnlos.operators.spectral.fold_spectrum`: a quarter of the memory)."""
        whole = self.fft.forward(cla.to_device(self.queue, kernel))
        return fold_spectrum(whole) if self.folded else whole

    def _separable_lobe(self, lobe: RetroLobe | None, footprint_rms_m: float,
                        terms: int | None, tolerance: float | None) -> SeparableLobe:
        """The lobe's separable terms on this grid: a [K, nv] over the u bins (their centre
        depths :attr:`u_depth_m`), b [K, |dy|, |dx|] over the padded grid's offsets; K =
        ``terms``, else the fewest within ``tolerance`` (default the lobe's own)."""
        n_off = lobe_offsets(self.pad_shape)
        if lobe is None or lobe.lambertian:
            return SeparableLobe(np.ones((1, self.nv)), np.ones((1,) + n_off), (0.0,),
                                 "lambertian" if lobe is None else lobe.name)
        z = self.u_depth_m
        G = lobe_weight_table(lobe, z, self.pitch_m, n_off, footprint_rms_m)
        return separable_terms(G, z, self.pitch_m, name=lobe.name, terms=terms,
                               tolerance=lobe.tolerance if tolerance is None else tolerance,
                               depth_extent=np.diff(self._u_edges_m))

    def _apply(self, x_g):
        if self.split:
            return self._apply_split(x_g)
        buf = self.scratch.array("a", self.pad_shape, self.dtype)
        spec = self.scratch.array("b", self.fft.spec_shape, self.fft.cdtype)
        acc = spec if len(self.H) == 1 else \
            self.scratch.array(LOBE_SLOT, self.fft.spec_shape, self.fft.cdtype)
        for k, (pre, H) in enumerate(zip(self._pre, self.H, strict=True)):
            fill_zero(self.queue, buf)
            pre.apply_into(x_g, buf)
            self.fft.forward(buf, spec, nonzero=self._in_block)
            if acc is spec:
                multiply_spectrum(self._k, H, spec, h_scale=1.0, adjoint=False,
                                  folded=self.folded)
            else:
                multiply_spectrum_into(self._k, H, spec, acc, adjoint=False,
                                       accumulate=k > 0, folded=self.folded)
        self.fft.inverse(acc, buf, needed=self._out_block)
        return self._post.apply_device(buf)

    def _apply_split(self, x_g):
        """:meth:`_apply` of K > 1 terms, split over the axes (module docstring)."""
        q, spec_shape, cd = self.queue, self.fft.spec_shape, self.fft.cdtype
        nv, ny = self.nv, self.in_shape[1]
        buf = self.scratch.array("a", self.pad_shape, self.dtype)
        fill_zero(q, buf)
        self._pre[0].apply_into(x_g, buf)
        lateral = self.scratch.array(LATERAL_SLOT, (nv,) + spec_shape[1:], cd)
        self.fft.forward_lateral(buf, lateral, rows=nv, nonzero_y=ny)
        term = self.scratch.array("b", spec_shape, cd)
        acc = self.scratch.array(LOBE_SLOT, spec_shape, cd)
        for k, (alpha, H) in enumerate(zip(self._alpha, self.H, strict=True)):
            scale_rows(self._k, lateral, term, alpha, rows=nv, accumulate=False,
                       zero_rows=spec_shape[0])
            self.fft.time_pass(term, inverse=False)
            multiply_spectrum_into(self._k, H, term, acc, adjoint=False, accumulate=k > 0,
                                   folded=self.folded)
        self.fft.inverse(acc, buf, needed=self._out_block)
        return self._post.apply_device(buf)

    def _adjoint_split(self, y_g):
        """:meth:`_adjoint` of K > 1 terms, split over the axes (module docstring)."""
        q, spec_shape, cd = self.queue, self.fft.spec_shape, self.fft.cdtype
        nv, ny = self.nv, self.in_shape[1]
        buf = self.scratch.array("a", self.pad_shape, self.dtype)
        fill_zero(q, buf)
        self._post.adjoint_into(y_g, buf)
        data = self.scratch.array(LOBE_SLOT, spec_shape, cd)
        self.fft.forward(buf, data, nonzero=self._out_block)
        term = self.scratch.array("b", spec_shape, cd)
        lateral = self.scratch.array(LATERAL_SLOT, (nv,) + spec_shape[1:], cd)
        for k, (alpha, H) in enumerate(zip(self._alpha, self.H, strict=True)):
            multiply_spectrum_into(self._k, H, data, term, adjoint=True, accumulate=False,
                                   folded=self.folded)
            self.fft.time_pass(term, inverse=True)
            scale_rows(self._k, term, lateral, alpha, rows=nv, accumulate=k > 0)
        self.fft.inverse_lateral(lateral, buf, rows=nv, needed_y=ny)
        return self._pre[0].adjoint_device(buf)

    def _adjoint(self, y_g):
        if self.split:
            return self._adjoint_split(y_g)
        buf = self.scratch.array("a", self.pad_shape, self.dtype)
        fill_zero(self.queue, buf)
        self._post.adjoint_into(y_g, buf)
        spec = self.scratch.array("b", self.fft.spec_shape, self.fft.cdtype)
        if len(self.H) == 1:
            self.fft.forward(buf, spec, nonzero=self._out_block)
            multiply_spectrum(self._k, self.H[0], spec, h_scale=1.0, adjoint=True,
                              folded=self.folded)
            self.fft.inverse(spec, buf, needed=self._in_block)
            return self._pre[0].adjoint_device(buf)
        data = self.scratch.array(LOBE_SLOT, self.fft.spec_shape, self.fft.cdtype)
        self.fft.forward(buf, data, nonzero=self._out_block)
        out = None
        for pre, H in zip(self._pre, self.H, strict=True):
            multiply_spectrum_into(self._k, H, data, spec, adjoint=True, accumulate=False,
                                   folded=self.folded)
            self.fft.inverse(spec, buf, needed=self._in_block)
            part = pre.adjoint_device(buf)
            out = part if out is None else out.__iadd__(part)
        return out

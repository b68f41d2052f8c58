"""Confocal inversion by f-k migration (Lindell, Wetzstein & O'Toole, SIGGRAPH 2019).

The confocal measurement is treated as a wavefield psi(x, y, t) recorded at z = 0 of an
exploding reflector moving at c/2: with t expressed as distance z_t = c t / 2, the
dispersion relation is k_t^2 = k_x^2 + k_y^2 + k_z^2. Steps (``kernels/fk.cl``):

1. psi = sqrt((t/T)^p tau), zero padded to (2M, 2Ny, 2Nx) (p = ``falloff``, default 2);
2. 3D FFT (real to half spectrum: psi is real); Stolt interpolation
   PSI'(k_z) = PSI(sqrt(k_z^2 + k_x^2 + k_y^2)) k_z / k_t for k_z > 0 (linear along k_t);
3. inverse FFT (of the rows k_z <= M - 1 alone, the rest being zero: the host FFT pads
   them along t itself), volume = |psi'|^2 on the unpadded block.

Same input/output contract as :class:`clnlos.inverse.lct.LCT`. Left out: BRDF, occlusions; the
square root assumes non-negative measurements (negative values are clipped to 0).
"""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla

from clnlos.physics.constants import C0
from clnlos.config import METHOD_FALLOFF
from clnlos.inverse.lct import check_inversion_args
from clnlos.inverse.methods import Inversion, InversionGrid
from clnlos.inverse.snr import CLOSED_FORM_SLAB_SNR_MIN
from clnlos.runtime.buffers import Scratch, fill_zero, kernel_int, round_up
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.fft import ComplexFFT3, RealFFT3
from clnlos.runtime.programs import get_kernels, real_defines

# the square root of the (t/T)^p-weighted measurement is the wave
DEFAULT_FALLOFF = METHOD_FALLOFF["fk"]


class FKMigration:
    def __init__(self, shape, *, bin_width_s: float, scan_width_m: float,
                 falloff: float = DEFAULT_FALLOFF,
                 dtype=np.float32, queue=None, scratch: Scratch | None = None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        nt, ny, nx = self.shape = check_inversion_args(shape, falloff)
        self.pad_shape = (2 * nt, 2 * ny, 2 * nx)
        dz = C0 * float(bin_width_s) / 2
        pitch = float(scan_width_m) / nx
        self.alpha_y = (nt * dz / (ny * pitch)) ** 2
        self.alpha_x = (nt * dz / (nx * pitch)) ** 2
        self.rfft = RealFFT3(self.pad_shape, self.dtype, self.queue)  # psi is real
        self.fft = ComplexFFT3(self.pad_shape, self.dtype, self.queue)
        self._k = get_kernels(self.queue, "fk", real_defines(self.dtype))
        w = ((np.arange(nt) + 0.5) / nt) ** falloff
        self._w = cla.to_device(self.queue, w.astype(self.dtype))
        # the Stolt-mapped spectrum is zero outside the rows kz = 1..kmax (kmax = nt - 1):
        # with the host FFT only rows 0..kmax are stored (the inverse pads them along t
        # itself: ComplexFFT3.inverse_low_rows), half the padded grid's complex size
        # (268 MB in place of 537 MB at 128 x 128 x 512); VkFFT takes the whole grid
        self.kmax = self.pad_shape[0] // 2 - 1
        self.mapped_shape = ((self.kmax + 1,) if self.fft.low_rows
                             else self.pad_shape[:1]) + self.pad_shape[1:]
        # scratch slot "a": the padded real wavefield, then (no longer needed) its
        # Stolt-mapped spectrum; slot "b": the half spectrum of the wavefield
        self.scratch = Scratch(self.queue) if scratch is None else scratch
        self.scratch.reserve("a", self.mapped_shape, self.fft.cdtype)
        self.scratch.reserve("b", self.rfft.spec_shape, self.fft.cdtype)

    def __call__(self, tau):
        on_device = isinstance(tau, cla.Array)
        x = tau if on_device else cla.to_device(self.queue,
                                                np.ascontiguousarray(tau, self.dtype))
        nt, ny, nx = self.shape
        pt, py, px = self.pad_shape
        q = self.queue
        psi = self.scratch.array("a", self.pad_shape, self.dtype)
        half = self.scratch.array("b", self.rfft.spec_shape, self.fft.cdtype)
        self._k.fk_prepare(q, (round_up(px, 8), round_up(py, 8), pt), None, x.data,
                           self._w.data, psi.data, kernel_int(nt), kernel_int(ny),
                           kernel_int(nx))
        self.rfft.forward(psi, half, nonzero=self.shape)
        del psi  # slot "a" now holds the Stolt-mapped spectrum
        out = self.scratch.array("a", self.mapped_shape, self.fft.cdtype)
        kmax = self.kmax  # rows kz = 1..kmax are mapped, the rest are 0
        row = py * px * out.dtype.itemsize
        fill_zero(q, out, 0, row)
        fill_zero(q, out, (kmax + 1) * row)
        nh = px // 2 + 1  # columns kx >= 0 are stored in the half spectrum
        for x0, n, mirrored in ((0, nh, 0), (nh, px - nh, 1)):
            if kmax >= 1 and n > 0:
                r = self.dtype.type
                self._k.stolt(q, (round_up(n, 8), round_up(py, 8), kmax), None, half.data,
                              out.data, kernel_int(pt), kernel_int(py), kernel_int(px),
                              r(self.alpha_y), r(self.alpha_x), kernel_int(x0),
                              np.int32(mirrored))
        self.fft.inverse_low_rows(out, needed=self.shape)  # fk_finish reads only that block
        vol = cla.empty(q, self.shape, self.dtype)
        self._k.fk_finish(q, (round_up(nx, 8), round_up(ny, 8), nt), None, out.data,
                          vol.data, kernel_int(nt), kernel_int(ny), kernel_int(nx))
        return vol if on_device else vol.get()


class FKMethod(Inversion):
    """``method = "fk"`` (:class:`FKMigration` behind the inversion contract of
    :mod:`clnlos.inverse.methods`; nothing of its own is chosen from the data; under the
    GCV rule its slab SNR has the floor CLOSED_FORM_SLAB_SNR_MIN, by default the
    reproducibility search chooses it, :mod:`clnlos.inverse.reproducibility`)."""

    name = "fk"
    slab_snr_min = CLOSED_FORM_SLAB_SNR_MIN  # Phi not modelled (clnlos.inverse.pipeline)
    slab_snr_toward_photons = True  # nothing regularised after the slab stage (ditto)

    def __init__(self, grid: InversionGrid, config, *, dtype, queue, scratch=None,
                 cache=None):
        super().__init__(grid, config, dtype=dtype, queue=queue, scratch=scratch, cache=cache)
        self.fk = FKMigration(grid.shape, **self.falloff(), **self.geometry())

    def __call__(self, tau_g, *, progress=None, setup=None):
        return self.fk(tau_g)

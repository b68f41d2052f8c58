"""Spectral filters on zero-padded 3D grids: convolution, its adjoint, Wiener deconvolution.

For a real volume x of shape (n0, n1, n2) and a PSF h on the padded grid P (wrap order:
zero lag/offset at index [0, 0, 0], see :func:`clnlos.diffusion.grid_offsets`)::

    convolve:  y = crop(F^-1[ H . F[pad(x)] ])
    wiener:    y = crop(F^-1[ conj(H) / (|H|^2 + 1/SNR) . F[pad(x)] ])

H = F[h] / H(0) (unit DC gain: 1/SNR is relative to |H(0)|^2 = 1) unless
``normalize=False``; the factor 1/H(0) is passed to the multiply kernels (``h_scale``), the
stored spectrum F[h] is never rescaled in a pass of its own. The multiply runs in
``kernels/wiener.cl``; FFTs from :mod:`clnlos.runtime.fft` (pyvkfft, host fallback) on the same
queue; the work buffers come from a :class:`clnlos.runtime.buffers.Scratch`. Padding the time
axis to at
least twice the causal PSF support keeps the circular convolution from wrapping.
"""

from __future__ import annotations

import weakref

import numpy as np
import pyopencl as cl
import pyopencl.array as cla
import scipy.sparse as sp

from clnlos.errors import ParameterError, ShapeError
from clnlos.operators.base import LinearOperator
from clnlos.operators.resample import AxisResample
from clnlos.physics.grid import fast_length, row_blocks
from clnlos.runtime.buffers import (
    Scratch,
    download,
    fill_zero,
    host_view,
    kernel_int,
    round_up,
    upload_into,
    upload_rows,
)
from clnlos.runtime.device import get_queue, is_oclgrind, require_dtype
from clnlos.runtime.fft import RealFFT3
from clnlos.runtime.programs import get_kernels, real_defines


def folded_shape(spec_shape) -> tuple[int, int, int]:
    """Shape of a folded half spectrum (``kernels/wiener.cl``): w <= n0 / 2, ky <= n1 / 2."""
    n0, n1, n2h = (int(v) for v in spec_shape)
    return (n0 // 2 + 1, n1 // 2 + 1, n2h)


def fold_spectrum(spec_g: cla.Array) -> cla.Array:
    """The folded quarter (:func:`folded_shape`) of the half spectrum ``spec_g`` of a PSF
    real and even in y and x: rows w <= n0 / 2, ky <= n1 / 2 copied into a new array on the device
    (one rectangular buffer copy); the kernels of ``kernels/wiener.cl`` restore the rest
    (H(w, -ky) = H(w, ky), H(-w) = conj(H(w))). A quarter of the memory of the whole."""
    n0, n1, n2h = spec_g.shape
    f0, f1, _ = folded_shape(spec_g.shape)
    out = cla.empty(spec_g.queue, (f0, f1, n2h), spec_g.dtype)
    if is_oclgrind(spec_g.queue.device):  # it marks no rectangular copy's bytes initialised
        with host_view(spec_g) as h:
            upload_into(out, h[:f0, :f1])
        return out
    row = n2h * spec_g.dtype.itemsize
    cl.enqueue_copy(spec_g.queue, out.base_data, spec_g.base_data,
                    src_origin=(spec_g.offset, 0, 0), dst_origin=(out.offset, 0, 0),
                    region=(row, f1, f0), src_pitches=(row, n1 * row),
                    dst_pitches=(row, f1 * row))
    return out


def multiply_spectrum(kernels, H: cla.Array, X: cla.Array, *, h_scale: float,
                      adjoint: bool, folded: bool = False, inv_snr: float | None = None):
    """X <- (h_scale H) X, its conjugate (``adjoint``), or the Wiener filter of it when
    ``inv_snr`` is given (``kernels/wiener.cl``; H whole or ``folded``), on X's
    (n0, n1, n2h) half-spectrum grid."""
    n0, n1, n2h = X.shape
    real = np.float32 if X.dtype == np.complex64 else np.float64
    gsize = (round_up(n2h, 8), n1, n0)
    tail = (np.int32(folded), kernel_int(n0), kernel_int(n1), kernel_int(n2h))
    if inv_snr is None:
        kernels.spectral_multiply(X.queue, gsize, None, H.data, X.data, real(h_scale),
                                  np.int32(adjoint), *tail)
    else:
        kernels.wiener_apply(X.queue, gsize, None, H.data, X.data, real(h_scale),
                             real(inv_snr), np.int32(adjoint), *tail)
    return X


def scale_rows(kernels, X: cla.Array, Y: cla.Array, weights: cla.Array, *, rows: int,
               accumulate: bool, zero_rows: int | None = None) -> cla.Array:
    """Y[w] <- weights[w] X[w], or added to Y (``accumulate``), for the rows w < ``rows`` of
    two complex arrays of (n1, n2h) planes (``kernels/wiener.cl``): a real weight per depth
    row of a spectrum transformed along y and x only; with ``zero_rows`` (not accumulating)
    Y's rows ``rows`` .. ``zero_rows`` - 1 set to 0 in the same pass (a zero-padded axis)."""
    n1, n2h = X.shape[1:]
    n_out = int(rows if zero_rows is None else max(zero_rows, rows))
    kernels.scale_rows(X.queue, (round_up(n2h, 8), n1, n_out), None, X.data, Y.data,
                       weights.data, np.int32(accumulate), kernel_int(rows),
                       kernel_int(n_out), kernel_int(n1), kernel_int(n2h))
    return Y


def kernel_support(kernel: np.ndarray, energy_tol: float) -> tuple[int, ...]:
    """Per axis, the smallest lag s such that the kernel's energy at |lag| > s (lags in wrap
    order on its grid) is at most ``energy_tol`` of the total (read row block by row
    block: a mapped device buffer is not copied whole)."""
    sums = [np.zeros(n) for n in kernel.shape]
    for r0, r1 in row_blocks(kernel.shape):
        e = np.square(kernel[r0:r1], dtype=np.float64)
        sums[0][r0:r1] = e.sum(axis=(1, 2))
        sums[1] += e.sum(axis=(0, 2))
        sums[2] += e.sum(axis=(0, 1))
    total = float(sums[0].sum())
    lags = []
    for e in sums:
        n = e.size
        lag = np.minimum(np.arange(n), n - np.arange(n))
        by_lag = np.bincount(lag, weights=e)
        beyond = total - np.cumsum(by_lag)  # energy at |lag| > s
        ok = np.flatnonzero(beyond <= energy_tol * total)
        lags.append(int(ok[0]) if ok.size else int(lag.max()))
    return tuple(lags)


def multiply_spectrum_into(kernels, H: cla.Array, X: cla.Array, Y: cla.Array, *,
                           adjoint: bool, accumulate: bool, h_scale: float = 1.0,
                           folded: bool = False):
    """Y <- (h_scale H) X or its conjugate (``adjoint``), added to Y when ``accumulate``
    (``kernels/wiener.cl``), on X's (n0, n1, n2h) half-spectrum grid (H whole or
    ``folded``)."""
    n0, n1, n2h = X.shape
    real = np.float32 if X.dtype == np.complex64 else np.float64
    kernels.spectral_multiply_into(X.queue, (round_up(n2h, 8), n1, n0), None, H.data, X.data,
                                   Y.data, real(h_scale), np.int32(adjoint),
                                   np.int32(accumulate), np.int32(folded), kernel_int(n0),
                                   kernel_int(n1), kernel_int(n2h))
    return Y


class SpectralFilter(LinearOperator):
    """Padded convolution (``mode="convolve"``) or Wiener deconvolution (``mode="wiener"``).

    Parameters
    ----------
    psf : ndarray or pyopencl Array, shape ``pad_shape``, real
        PSF on the padded grid in wrap order.
    in_shape : (n0, n1, n2)
        Shape of the volumes filtered (placed at the low corner of the padded grid).
    snr : float, for ``mode="wiener"``: 1/SNR regularises the inverse.
    psf_support : (n0, n1, n2), optional
        The PSF is zero outside its low-corner block of this shape (the FFT skips the rest).
    scratch : :class:`clnlos.runtime.buffers.Scratch`, optional
        Work buffers shared with the other stages of a plan (slots ``"a"``: the padded
        real grid, ``"b"``: its spectrum); a private one by default.
    spectrum : pyopencl Array, optional
        F[psf] already computed on this grid (half spectrum, complex); ``psf`` is then the
        padded shape (a tuple).
    spectrum_folded : bool
        ``spectrum`` is stored folded (:func:`folded_shape`: a PSF real and even in y and x).
    lateral_pad : ``"zero"`` (default; the operator has an exact adjoint) or ``"mirror"``
        (even extension across the scan border, needs a (.., 2 ny, 2 nx) grid): for
        deconvolving data whose blur reached past the scanned area, where zero padding puts
        a step at the border and the inverse filter rings there.
    """

    name = "spectral_filter"

    def __init__(self, psf, in_shape, *, mode: str = "convolve", snr: float | None = None,
                 normalize: bool = True, lateral_pad: str = "zero", dtype=np.float32,
                 queue=None, spectrum: cla.Array | None = None,
                 scratch: Scratch | None = None, psf_support=None,
                 spectrum_folded: bool = False):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        if mode not in ("convolve", "wiener"):
            raise ParameterError("mode", mode, "'convolve' or 'wiener'")
        self.mode = mode
        if mode == "wiener":
            if snr is None or not np.isfinite(snr) or snr <= 0:
                raise ParameterError("snr", snr, "> 0 and finite")
            self.inv_snr = 1.0 / float(snr)
        else:
            self.inv_snr = 0.0
        self.name = f"{mode}_filter"
        pad_shape = tuple(int(s) for s in (psf.shape if hasattr(psf, "shape") else psf))
        self.in_shape = self.out_shape = tuple(int(s) for s in in_shape)
        if len(pad_shape) != 3 or any(p < n for p, n in zip(pad_shape, self.in_shape,
                                                             strict=True)):
            raise ShapeError(f"padded PSF shape {pad_shape} must cover the volume {in_shape}")
        self.pad_shape = pad_shape
        n0, n1, n2 = self.in_shape
        if lateral_pad not in ("zero", "mirror"):
            raise ParameterError("lateral_pad", lateral_pad, "'zero' or 'mirror'")
        if lateral_pad == "mirror" and pad_shape[1:] != (2 * n1, 2 * n2):
            raise ShapeError(f"mirror padding needs a (.., {2 * n1}, {2 * n2}) grid, "
                             f"got {pad_shape}")
        self.lateral_pad = lateral_pad
        self._rk = get_kernels(self.queue, "resample", real_defines(self.dtype))
        self._pad = AxisResample(sp.identity(n0, format="csr"), (n1, n2), dtype=self.dtype,
                                 queue=self.queue, out_plane=pad_shape[1:],
                                 out_rows=pad_shape[0])
        self.fft = RealFFT3(pad_shape, self.dtype, self.queue)
        self.kernels = get_kernels(self.queue, "wiener", real_defines(self.dtype))
        self.folded = bool(spectrum is not None and spectrum_folded)
        if spectrum is not None:
            want = folded_shape(self.fft.spec_shape) if self.folded else self.fft.spec_shape
            if tuple(spectrum.shape) != want:
                raise ShapeError(f"spectrum of shape {tuple(spectrum.shape)}; the grid "
                                 f"{pad_shape} needs {want}")
            self.H = spectrum
        else:
            psf_g = psf if isinstance(psf, cla.Array) else cla.to_device(
                self.queue, np.ascontiguousarray(psf, self.dtype))
            if psf_g.dtype != self.dtype:
                psf_g = psf_g.astype(self.dtype)
            self.H = self.fft.forward(psf_g, nonzero=psf_support)
        self.dc_gain = float(download(self.H[0, 0, 0:1])[0].real) if self.H.size else 0.0
        self.h_scale = 1.0  # the kernels multiply by h_scale * H
        if normalize:
            if not self.dc_gain > 0:
                raise ParameterError("psf", f"sum {self.dc_gain}", "> 0 (a non-negative PSF)")
            self.h_scale = 1.0 / self.dc_gain
        self.scratch = Scratch(self.queue) if scratch is None else scratch
        self.scratch.reserve("a", pad_shape, self.dtype)
        self.scratch.reserve("b", self.fft.spec_shape, self.fft.cdtype)
        self.kept = None  # (input, slot "b" requests) of the spectrum power_blocks left

    @property
    def work_buffer(self) -> cla.Array:
        """The padded real grid (scratch slot "a"; every call overwrites all of it)."""
        return self.scratch.array("a", self.pad_shape, self.dtype)

    @classmethod
    def from_spectrum(cls, base: SpectralFilter, H: cla.Array, *, mode: str,
                      snr: float | None = None, h_scale: float | None = None
                      ) -> SpectralFilter:
        """A filter sharing ``base``'s grid and plans with another spectrum, applied as
        ``h_scale * H`` (default: ``base``'s normalisation when H is ``base.H``, else 1)."""
        new = object.__new__(cls)
        new.__dict__.update(base.__dict__)
        new.mode, new.name = mode, f"{mode}_filter"
        new.inv_snr = 0.0 if mode == "convolve" else 1.0 / float(snr)
        new.H = H
        new.h_scale = (base.h_scale if H is base.H else 1.0) if h_scale is None else h_scale
        new.folded = base.folded if H is base.H else False
        new.kept = None
        return new

    def set_snr(self, snr: float) -> None:
        """Change the Wiener SNR of this filter (a per-capture choice; no rebuild)."""
        if self.mode != "wiener":
            raise ParameterError("snr", snr, "only for mode='wiener'")
        if snr is None or not np.isfinite(snr) or snr <= 0:
            raise ParameterError("snr", snr, "> 0 and finite")
        self.inv_snr = 1.0 / float(snr)

    def _padder(self, x_g: cla.Array, adjoint: bool = False):
        """(write_input, nonzero, zeroed) of :meth:`filter_padded` for ``x_g``: the mirror
        extension (forward filter with ``lateral_pad="mirror"``) or zero padding."""
        n0, n1, n2 = self.in_shape
        if self.lateral_pad == "mirror" and not adjoint:
            p0, p1, p2 = self.pad_shape

            def write(buf):
                self._rk.pad_mirror_xy(self.queue, (round_up(p2, 8), round_up(p1, 8), p0),
                                       None, x_g.data, buf.data, kernel_int(n0),
                                       kernel_int(n1), kernel_int(n2), kernel_int(p0))
            return write, (n0, p1, p2), False
        return (lambda buf: self._pad.apply_into(x_g, buf)), None, True

    def _filter(self, x_g: cla.Array, adjoint: bool) -> cla.Array:
        write, nonzero, zeroed = self._padder(x_g, adjoint)
        return self.filter_padded(write, self._pad.adjoint_device, adjoint=adjoint, nonzero=nonzero,
                                  zeroed=zeroed, source=None if adjoint else x_g)

    def gain_squared(self) -> np.ndarray:
        """|h_scale H|^2 on the (n0, n1, n2h) half-spectrum grid, unfolded (host, float64):
        the squared gain of the filter's PSF at every frequency of :meth:`power_blocks`."""
        return self.gain_rows(0, self.fft.spec_shape[0])

    def gain_rows(self, r0: int, r1: int) -> np.ndarray:
        """Rows r0:r1 of :meth:`gain_squared` (host, float64), read from the device block by
        block (:meth:`clnlos.inverse.gcv.GcvBins.from_blocks`: no host copy of the whole
        spectrum)."""
        n0, n1 = self.fft.spec_shape[:2]
        if not self.folded:
            return self.stored_gain_rows(r0, r1)
        w = np.arange(r0, r1)
        fw = np.minimum(w, n0 - w)
        lo, hi = int(fw.min()), int(fw.max()) + 1
        g = self.stored_gain_rows(lo, hi)
        ky = np.arange(n1)
        return g[fw - lo][:, np.minimum(ky, n1 - ky)]

    def stored_gain_rows(self, r0: int, r1: int) -> np.ndarray:
        """|h_scale H|^2 of the stored rows r0:r1 of the spectrum (host, float64): the
        whole half spectrum's rows, or the folded quarter's (:func:`folded_shape`) when
        :attr:`folded`. Copied with :func:`clnlos.runtime.buffers.download` (``.get()``
        would keep each block's host copy alive in the spectrum's event list)."""
        h = download(self.H[r0:r1])
        return (h.real.astype(np.float64) ** 2 + h.imag.astype(np.float64) ** 2) \
            * self.h_scale**2

    def power_blocks(self, blocks, x_g: cla.Array | None = None, *, write_input=None,
                     nonzero=None, source=None):
        """The power spectrum |F[pad(x)]|^2 of the input as this filter pads it (``x_g``), or
        as ``write_input(buf)`` writes it into the zeroed padded grid (data in its
        low-corner ``nonzero`` block), block by block: yields (r0, rows r0:r1 of it, float32)
        for each (r0, r1) of ``blocks`` (rows of the half spectrum), after one forward FFT;
        no host array of the spectrum's size (a GCV bin sum,
        :class:`clnlos.inverse.gcv.BinnedPower`, needs no more). The spectrum stays in the
        work buffer: the next :meth:`filter_padded` of the same input (``x_g``, or the array
        ``source`` that ``write_input`` writes) skips its forward transform when nothing
        has asked for that buffer since (an SNR chosen, then the data filtered with it)."""
        zeroed = True
        if write_input is None:
            write_input, nonzero, zeroed = self._padder(x_g)
            source = x_g
        _, spec = self._forward_padded(write_input, nonzero, zeroed)
        # a weak reference: a kept spectrum never keeps its input alive
        self.kept = None if source is None else (weakref.ref(source),
                                                  self.scratch.requests["b"])
        for r0, r1 in blocks:
            s = download(spec[r0:r1])  # not .get(): the blocks' copies are not kept alive
            yield r0, s.real * s.real + s.imag * s.imag

    def influence(self, in_shape=None, energy_tol: float | None = None) -> SpectralFilter:
        """The Wiener filter's influence ("hat") operator: this filter applied after the blur
        it inverts, phi_k = |h H_k|^2 / (|h H_k|^2 + 1/SNR) (real, in [0, 1)), as a
        zero-padded convolution for volumes of ``in_shape`` (default its own; fewer rows:
        the data end there, the rows past them zero). Self-adjoint, norm below 1; the SNR
        is the one set now (``mode="wiener"`` only).

        On this filter's grid; with ``energy_tol``, its kernel (real and even: phi is real)
        cut to the lags s = (s_t, s_y, s_x) that hold all but that fraction of its energy
        and convolved on the smallest FFT-friendly grid of at least n + s per axis (n the
        volume's size), where that cut kernel does not wrap: the same operator up to
        ``energy_tol`` of the kernel's energy, at a fraction of the grid (phi is compact:
        a ratio of the blur's gain that is flat wherever the blur is well above 1/SNR)."""
        if self.mode != "wiener":
            raise ParameterError("mode", self.mode, "'wiener' (a filter with an influence)")
        in_shape = self.in_shape if in_shape is None else tuple(int(v) for v in in_shape)
        phi = cla.empty(self.queue, self.fft.spec_shape, self.fft.cdtype)
        for r0, r1 in row_blocks(phi.shape):
            g = self.gain_rows(r0, r1)
            upload_rows(phi, r0, (g / (g + self.inv_snr)).astype(self.fft.cdtype))
        whole = SpectralFilter(self.pad_shape, in_shape, mode="convolve", normalize=False,
                               lateral_pad="zero", dtype=self.dtype, queue=self.queue,
                               spectrum=phi, scratch=self.scratch)
        if energy_tol is None:
            return whole
        kernel = self.fft.inverse(phi.copy(), cla.empty(self.queue, self.pad_shape, self.dtype))
        with host_view(kernel) as k:
            lags = kernel_support(k, energy_tol)
        grid = tuple(fast_length(n + s) for n, s in zip(in_shape, lags, strict=True))
        if np.prod(grid) >= np.prod(self.pad_shape):
            return whole
        idx = [np.arange(-s, s + 1) for s in lags]
        with host_view(kernel) as k:
            cut = k[np.ix_(*[i % n for i, n in zip(idx, self.pad_shape, strict=True)])]
        small = np.zeros(grid, self.dtype)
        small[np.ix_(*[i % n for i, n in zip(idx, grid, strict=True)])] = cut
        return SpectralFilter(small, in_shape, mode="convolve", normalize=False,
                              lateral_pad="zero", dtype=self.dtype, queue=self.queue,
                              scratch=self.scratch)

    def _forward_padded(self, write_input, nonzero, zeroed: bool):
        """(the padded grid, its half spectrum): ``write_input(buf)`` into the padded grid
        (zeroed first if ``zeroed``; data in its low-corner ``nonzero`` block, default
        ``in_shape``), then the forward FFT into scratch slot "b"."""
        buf = self.work_buffer
        if zeroed:
            fill_zero(self.queue, buf)
        write_input(buf)
        spec = self.fft.forward(buf, self.scratch.array("b", self.fft.spec_shape,
                                                        self.fft.cdtype),
                                nonzero=self.in_shape if nonzero is None else nonzero)
        return buf, spec

    def filter_padded(self, write_input, read_output, *, adjoint: bool = False,
                      nonzero=None, zeroed: bool = True, source=None):
        """The filter with the padding and the crop done by the caller's own passes:
        ``write_input(buf)`` writes the input into the padded grid ``buf`` (zeroed first
        unless ``zeroed=False``; data only in its low-corner ``nonzero`` block, default
        ``in_shape``), ``read_output(buf)`` reads the result from its ``in_shape`` block
        (the rest of ``buf`` is not computed). A resampling that writes straight into the
        padded grid saves the separate pad and crop passes (LCT's t -> v and u -> z).
        ``source``: the array ``write_input`` writes, whose spectrum :meth:`power_blocks` may
        have left in the work buffer (then reused: no forward transform)."""
        spec = self._kept_spectrum(source)
        if spec is None:
            buf, spec = self._forward_padded(write_input, nonzero, zeroed)
        else:
            buf = self.work_buffer
        multiply_spectrum(self.kernels, self.H, spec, h_scale=self.h_scale, adjoint=adjoint,
                          folded=self.folded,
                          inv_snr=self.inv_snr if self.mode == "wiener" else None)
        self.fft.inverse(spec, buf, needed=self.in_shape)
        return read_output(buf)

    def _kept_spectrum(self, source):
        """The spectrum of ``source`` that :meth:`power_blocks` left in slot "b", or None:
        another input, or the slot asked for since (its contents may have changed). Used
        once: the filter overwrites it."""
        kept, self.kept = self.kept, None
        if source is None or kept is None or kept[0]() is not source or \
                kept[1] != self.scratch.requests.get("b"):
            return None
        return self.scratch.array("b", self.fft.spec_shape, self.fft.cdtype)

    def _apply(self, x_g):
        return self._filter(x_g, adjoint=False)

    def _adjoint(self, y_g):
        if self.lateral_pad != "zero":
            raise NotImplementedError("the adjoint is defined for zero padding only")
        return self._filter(y_g, adjoint=True)

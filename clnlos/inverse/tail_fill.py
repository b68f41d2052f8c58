"""Slab deconvolution of a capture whose time window ends before the blur of its latest
arrivals has decayed: the unseen tail filled from the model (Gerchberg-Papoulis / EM fill)."""

from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla

from clnlos.errors import ShapeError
from clnlos.forward.blur import BlurTimeScales, slab_blur
from clnlos.operators.spectral import SpectralFilter
from clnlos.physics.grid import block_sums
from clnlos.physics.slab import Slab
from clnlos.runtime.buffers import Scratch, copy_rows, download, fill_zero
from clnlos.runtime.device import has_fp64

TAIL_FILL_ITERATIONS = 12    # at most this many fills of the unseen tail


TAIL_FILL_RTOL = 1e-3        # ... stopping when the fill changes by less than this (rel. L2)
TAIL_FILL_SNR = 1e4          # the fill's Wiener SNR at most (see TailFilledDeconvolution)
TAIL_FILL_SNR_MIN = 1e2      # ... lowered 10x at a time while the fill diverges, to this
TAIL_FILLED_SNR_MAX = 1e8    # the final deconvolution of a filled window's SNR at most
# the fill runs on scan cells summed in f x f blocks, f * pitch at most this multiple of the
# slab's diffuse spot scale d + 2 z_e (the tail is the blur of arrivals at lags past its
# peak, laterally as wide as that spot), at least TAIL_FILL_POINTS_MIN blocks per side
TAIL_FILL_CELL_OF_SPOT = 2.0
TAIL_FILL_POINTS_MIN = 16


class TailFilledDeconvolution:
    """Wiener deconvolution of a transient whose time window ends before the slab's blur of
    its latest arrivals has decayed.

    Deconvolving the window as it is treats the light still leaving the slab at its end as
    a step down to zero, which the inverse filter turns into the brightest feature of the
    volume, near its end (a target at 0.5 m placed at 0.76 m with a 5.1 ns window). Here the
    time axis is padded by the blur's reach R (:class:`BlurTimeScales`) and the unseen tail
    is filled in with the model's own prediction: with M the window [0, n) and
    x_k = W y_k (W the Wiener filter on the n + R grid),

        y_0 = (tau, 0),    y_{k+1} = (tau, [H P x_k]_{t >= n}),

    H the blur and P the restriction of x to t < n - peak (arrivals whose brightest part
    lies inside the window; later ones are not determined by the data). This is the
    Gerchberg-Papoulis / EM fill of missing samples; it converges in a few iterations
    (TAIL_FILL_RTOL) because P removes what the tail alone would explain. The result is
    P x_K on [0, n): arrivals in the last ``peak`` bins are left out (zero), since only the
    rise of their response is in the window and the inverse filter would turn it into the
    brightest voxels of the volume.

    The fill's W runs at min(snr, TAIL_FILL_SNR); only the final x_K = W y_K takes the
    deconvolution's own SNR, at most TAIL_FILLED_SNR_MAX (``applied_snr``): the filled tail
    agrees with the true one only to the fill's accuracy, and a near-inverse final filter
    (the noise-free cap, 1e10) turns that mismatch at the window's end into voxels past the
    target (docs/validation/parameter-rules.md). The fill is H P x_k, blurred again by H,
    so it needs only what a moderate SNR already restores; a near-inverse W (SNR
    1e8-1e10: noise-free captures, 1e12 photons) makes the fixed-point iteration diverge
    instead (85 bins of 96 ps, a 5.1 ns tail: the fill grows 49x per step, a target at
    0.5 m reconstructed at 1.1 m).
    Measured there, the fill's error against the true tail is 0.6% at SNR 1e4, 1.3% at 1e5,
    1.4% at 1e6; from 1e7 it diverges. Should the fill still diverge (a change larger than
    its first), its SNR is lowered tenfold and the fill restarted, down to
    TAIL_FILL_SNR_MIN (diverging there too, the tail is left zero); ``fill_snr`` records
    the SNR the fill ran at.

    The fill runs on a coarser scan grid (:func:`fill_block`: f x f scan cells summed, f *
    pitch at most TAIL_FILL_CELL_OF_SPOT times the slab's diffuse spot scale d + 2 z_e): the
    tail is H P x at lags past the blur's peak, as wide laterally as the slab's diffuse spot,
    so f x f blocks carry it, and the iteration costs 1/f^2 of the capture's grid (measured:
    docs/performance.md, "f-k and LCT at 128^3 behind the slab"). W is linear, so the final
    deconvolution of the filled window splits,

        x = [W (tau, tail)]_{t < n} ~ W_n tau + [W (0, tail)]_{t < n},

    W_n the plain Wiener filter of the window (``window_filter``: the pipeline's own, shared;
    every user of it sets its SNR before a call, as this class does) and the tail's response
    computed on the fill's grid, divided by f^2 and interpolated (bilinear between block
    centres) onto the scan grid: approximately, as W_n pads the n rows and the fill's W the
    n + reach rows each to its own grid, and the fill's grid holds the tail's lateral
    frequencies up to its blocks' (the errors measured there). With f = 1 the filled window
    is filtered as it is, on the n + reach grid. ``block`` records f.
    """

    name = "tail_filled_wiener"

    def __init__(self, slab: Slab, shape, *, bin_width_s: float, pitch_m: float,
                 scales: BlurTimeScales, snr: float = 1.0, n_dipoles=None,
                 lateral_pad: str = "zero", dtype=np.float32, queue=None, scratch=None,
                 cache=None, window_filter: SpectralFilter | None = None):
        n, ny, nx = (int(v) for v in shape)
        self.in_shape = self.out_shape = (n, ny, nx)
        self.scales = scales
        self.n_ext = n + scales.reach_lags
        self.n_known = max(0, n - scales.peak_lags)  # arrivals the window determines
        blur = dict(bin_width_s=bin_width_s, mode="wiener", snr=snr, n_dipoles=n_dipoles,
                    lateral_pad=lateral_pad, dtype=dtype, queue=queue, cache=cache)
        self.W = window_filter if window_filter is not None else slab_blur(
            slab, self.in_shape, pitch_m=pitch_m, scratch=scratch, **blur)
        if self.W.in_shape != self.in_shape:
            raise ShapeError(f"tail fill: a window filter of {self.W.in_shape} for windows of "
                             f"{self.in_shape}")
        self.queue = self.W.queue
        self.block = f = fill_block(slab, ny, nx, pitch_m)
        self.fill_shape = (self.n_ext, ny // f, nx // f)
        # on blocks, work buffers of its own: the pipeline's stay sized for the scan grid
        self.W_fill = slab_blur(slab, self.fill_shape, pitch_m=pitch_m * f,
                                scratch=scratch if f == 1 else Scratch(self.queue), **blur)
        self.H = SpectralFilter.from_spectrum(self.W_fill, self.W_fill.H, mode="convolve")
        self.snr = float(snr)
        self.fill_snr = min(self.snr, TAIL_FILL_SNR)
        self.iterations_run = 0

    def set_snr(self, snr: float) -> None:
        self.snr = float(snr)

    @property
    def applied_snr(self) -> float:
        """The SNR of the final deconvolution: min(snr, TAIL_FILLED_SNR_MAX) (the filled
        tail is a model prediction, not data a near-inverse filter may trust)."""
        return min(self.snr, TAIL_FILLED_SNR_MAX)

    def __call__(self, tau_g: cla.Array, memo: dict | None = None) -> cla.Array:
        """The deconvolution of ``tau_g`` at the set SNR; ``memo`` (a dict kept by the
        caller for this one input): the fills by fill SNR, computed once (the fill depends
        on the SNR only through min(snr, TAIL_FILL_SNR): the slab SNRs a search tries share
        it)."""
        plane = self.in_shape[1] * self.in_shape[2]
        item = tau_g.dtype.itemsize
        fill_snr = min(self.snr, TAIL_FILL_SNR)
        memo = {} if memo is None else memo
        while True:
            if fill_snr not in memo:
                memo[fill_snr] = self._fill(self._fill_input(tau_g), fill_snr)
            tail, diverged = memo[fill_snr]
            if not diverged:
                break
            if fill_snr <= TAIL_FILL_SNR_MIN:  # no fill to trust: the window as it is
                tail = None
                break
            fill_snr = max(fill_snr / 10.0, TAIL_FILL_SNR_MIN)
        self.fill_snr = fill_snr
        if tail is not None and self.block == 1:  # the fill's grid is the window's: W of
            x = self._filled_window_filtered(tau_g, tail)  # the filled window, one filter
        else:
            self.W.set_snr(self.applied_snr)
            x = self.W(tau_g)
            if tail is not None and self.n_known:
                x[:self.n_known] += self._tail_response(tail)
        # arrivals past n - peak are seen only by the rise of their response: not determined
        fill_zero(self.queue, x, offset_bytes=self.n_known * plane * item)
        return x

    def _extended(self, head: cla.Array | None, tail: cla.Array | None,
                  dtype) -> cla.Array:
        """The fill's grid [n + reach, y', x']: ``head`` in rows 0..n (zero where None), ``tail``
        in rows n.. (zero where None)."""
        n = self.in_shape[0]
        row = self.fill_shape[1] * self.fill_shape[2] * np.dtype(dtype).itemsize
        y = cla.empty(self.queue, self.fill_shape, dtype)
        if head is None:
            fill_zero(self.queue, y, nbytes=n * row)
        else:
            copy_rows(self.queue, head, y, rows=n)
        if tail is None:
            fill_zero(self.queue, y, offset_bytes=n * row)
        else:
            copy_rows(self.queue, tail, y, rows=self.n_ext - n, dst_row=n)
        return y

    def _filled_window_filtered(self, tau_g: cla.Array, tail: cla.Array) -> cla.Array:
        """[W (tau, tail)]_{t < n} on the fill's grid (the scan grid where f = 1)."""
        self.W_fill.set_snr(self.applied_snr)
        return self.W_fill(self._extended(tau_g, tail, tau_g.dtype))[:self.in_shape[0]]

    def _tail_response(self, tail: cla.Array) -> cla.Array:
        """[W (0, tail)]_{t < n - peak} on the scan grid: the filled tail's part of the final
        deconvolution (class docstring) on the rows it keeps, at :attr:`applied_snr`, on the
        fill's grid."""
        self.W_fill.set_snr(self.applied_snr)
        return self._on_scan_grid(self.W_fill(self._extended(None, tail, tail.dtype))
                                  [:self.n_known])

    def _fill_input(self, tau_g: cla.Array) -> cla.Array:
        """The window on the fill's grid: ``tau_g`` with its scan cells summed in blocks of
        :attr:`block` per side (itself where the block is one cell)."""
        if self.block == 1:
            return tau_g
        return cla.to_device(self.queue, block_sums(download(tau_g), self.block))

    def _on_scan_grid(self, part: cla.Array) -> cla.Array:
        """Rows [t, y', x'] of the fill's grid on the scan grid: per cell, divided by the
        cells a block sums, interpolated bilinearly between block centres (held at the
        border)."""
        f = self.block
        return cla.to_device(self.queue, block_interpolated(download(part), f) / (f * f))

    def _fill(self, tau_g: cla.Array, fill_snr: float) -> tuple[cla.Array, bool]:
        """(the model-predicted tail of the window ``tau_g`` on the fill's grid, rows n ...
        n + reach, diverged): the fill iteration of the class docstring with W at
        ``fill_snr``; diverged when a change of the fill exceeds its first change (a
        contracting iteration's changes stay below it, down to float32's plateau; a
        diverging one's grow by the spectral radius, 49x at 85 bins of 96 ps and SNR
        1e10)."""
        n = self.in_shape[0]
        plane = self.fill_shape[1] * self.fill_shape[2]
        item = tau_g.dtype.itemsize
        W = self.W_fill
        W.set_snr(fill_snr)
        y = self._extended(tau_g, None, tau_g.dtype)
        tail = y[n:]  # a view: the rows the fill writes
        tail_old = cla.empty_like(tail)
        first_change = None
        self.iterations_run = 0
        for k in range(TAIL_FILL_ITERATIONS - 1):
            if k:
                copy_rows(self.queue, tail, tail_old, rows=self.n_ext - n)
            x = W(y)
            self.iterations_run = k + 1
            fill_zero(self.queue, x, offset_bytes=self.n_known * plane * item)
            hx = self.H(x)
            copy_rows(self.queue, hx, y, rows=self.n_ext - n, src_row=n, dst_row=n)
            if not k:
                continue
            # the fill's change: two reductions on the device, two numbers read back
            scale, change = tail_change(tail, tail_old)
            if not np.isfinite(change) or (first_change is not None and change > first_change):
                return None, True
            if change < TAIL_FILL_RTOL * max(scale, 1e-300):
                break
            first_change = change if first_change is None else first_change
        return tail, False


def fill_block(slab: Slab, ny: int, nx: int, pitch_m: float) -> int:
    """Scan cells per side the tail fill sums (:class:`TailFilledDeconvolution`): the largest
    f dividing ``ny`` and ``nx`` with f * ``pitch_m`` <= TAIL_FILL_CELL_OF_SPOT (d + 2 z_e)
    and at least TAIL_FILL_POINTS_MIN blocks per side (1 where none does)."""
    spot = TAIL_FILL_CELL_OF_SPOT * (slab.thickness_m + 2.0 * slab.ze)
    best = 1
    for f in range(2, min(ny, nx) // TAIL_FILL_POINTS_MIN + 1):
        if ny % f == 0 and nx % f == 0 and f * pitch_m <= spot:
            best = f
    return best


def block_interpolated(a: np.ndarray, f: int) -> np.ndarray:
    """[t, Y, X] of block values -> [t, f Y, f X]: bilinear between the blocks' centres (at
    fine-cell coordinates f j + (f - 1) / 2), constant past the outermost centres; applied
    as M_y a[t] M_x^T with the (f m, m) interpolation matrices of :func:`linear_weights`."""
    if f == 1:
        return np.asarray(a)
    my = linear_weights(a.shape[1], f).astype(a.dtype)
    mx = linear_weights(a.shape[2], f).astype(a.dtype)
    return np.ascontiguousarray(np.matmul(np.matmul(my, a), mx.T), a.dtype)


def linear_weights(m: int, f: int) -> np.ndarray:
    """(f m, m) matrix of linear interpolation from m block centres (at f j + (f - 1) / 2
    in fine-cell units) to the f m fine cells, held constant past the outermost centres."""
    pos = np.clip((np.arange(m * f) - (f - 1) / 2.0) / f, 0.0, m - 1.0)
    lo = np.minimum(np.floor(pos).astype(int), max(m - 2, 0))
    hi = np.minimum(lo + 1, m - 1)
    w = pos - lo
    out = np.zeros((m * f, m))
    rows = np.arange(m * f)
    np.add.at(out, (rows, lo), 1.0 - w)
    np.add.at(out, (rows, hi), w)
    return out


def tail_change(tail: cla.Array, old: cla.Array) -> tuple[float, float]:
    """(||tail||, ||tail - old||) of two device arrays, reduced on the device (float64 where
    the device has it: the sums of squares of a float32 tail)."""
    acc = np.float64 if has_fp64(tail.queue.device) else np.float32
    d = tail - old
    s2 = float(cla.dot(tail, tail, dtype=acc).get())
    c2 = float(cla.dot(d, d, dtype=acc).get())
    return math.sqrt(max(s2, 0.0)), math.sqrt(max(c2, 0.0))

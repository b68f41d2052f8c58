"""Slab deconvolution of a capture whose time window ends before the blur of its latest
arrivals has decayed: the unseen tail filled from the model (Gerchberg-Papoulis / EM fill)."""

from __future__ import annotations

import numpy as np
import pyopencl.array as cla

from clnlos.forward.blur import BlurTimeScales, slab_blur
from clnlos.operators.spectral import SpectralFilter
from clnlos.physics.slab import Slab
from clnlos.runtime.buffers import copy_rows, fill_zero, host_view

TAIL_FILL_ITERATIONS = 12    # at most this many fills of the unseen tail


TAIL_FILL_RTOL = 1e-3        # ... stopping when the fill changes by less than this (rel. L2)


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
    """

    name = "tail_filled_wiener"

    def __init__(self, slab: Slab, shape, *, bin_width_s: float, pitch_m: float,
                 scales: BlurTimeScales, snr: float = 1.0, n_dipoles=None,
                 lateral_pad: str = "zero", dtype=np.float32, queue=None, scratch=None,
                 cache=None):
        n, ny, nx = (int(v) for v in shape)
        self.in_shape = self.out_shape = (n, ny, nx)
        self.scales = scales
        self.n_ext = n + scales.reach_lags
        self.n_known = max(0, n - scales.peak_lags)  # arrivals the window determines
        self.W = slab_blur(slab, (self.n_ext, ny, nx), bin_width_s=bin_width_s,
                           pitch_m=pitch_m, mode="wiener", snr=snr, n_dipoles=n_dipoles,
                           lateral_pad=lateral_pad, dtype=dtype, queue=queue,
                           scratch=scratch, cache=cache)
        self.H = SpectralFilter.from_spectrum(self.W, self.W.H, mode="convolve")
        self.queue = self.W.queue
        self.iterations_run = 0

    def set_snr(self, snr: float) -> None:
        self.W.set_snr(snr)

    def __call__(self, tau_g: cla.Array) -> cla.Array:
        n = self.in_shape[0]
        plane = self.in_shape[1] * self.in_shape[2]
        item = tau_g.dtype.itemsize
        y = cla.empty(self.queue, (self.n_ext,) + self.in_shape[1:], tau_g.dtype)
        copy_rows(self.queue, tau_g, y, rows=n)
        fill_zero(self.queue, y, offset_bytes=n * plane * item)
        tail_old = None
        for k in range(TAIL_FILL_ITERATIONS):
            x = self.W(y)
            self.iterations_run = k + 1
            if k == TAIL_FILL_ITERATIONS - 1:
                break
            fill_zero(self.queue, x, offset_bytes=self.n_known * plane * item)
            hx = self.H(x)
            copy_rows(self.queue, hx, y, rows=self.n_ext - n, src_row=n, dst_row=n)
            with host_view(y) as yh:  # the fill's change (small reductions on the host)
                tail = np.array(yh[n:], dtype=np.float64)
            if tail_old is not None:
                scale = max(float(np.linalg.norm(tail)), 1e-300)
                if float(np.linalg.norm(tail - tail_old)) < TAIL_FILL_RTOL * scale:
                    x = self.W(y)
                    self.iterations_run = k + 2
                    break
            tail_old = tail
        # arrivals past n - peak are seen only by the rise of their response: not determined
        fill_zero(self.queue, x, offset_bytes=self.n_known * plane * item)
        return x[:n]

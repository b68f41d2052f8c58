"""The laser pulse as a temporal blur of transients [t, y, x] (``kernels/temporal.cl``).

    out[t] = sum_{k=-K..K} g[k] in[t - k]      (zero outside the window)

with g the bin-integrated Gaussian of the pulse's FWHM, truncated at 5 sigma and summing to
1. The adjoint is the correlation with g (the convolution with the reversed taps; g is
symmetric, so the operator is self-adjoint up to the window's edges, where both are exact).
"""

from __future__ import annotations

import math

import numpy as np
import pyopencl.array as cla
from scipy.special import erf

from clnlos.operators.base import LinearOperator
from clnlos.runtime.buffers import kernel_int, round_up
from clnlos.runtime.device import get_queue, require_dtype
from clnlos.runtime.programs import get_kernels, real_defines


def pulse_taps(pulse_width_s: float, bin_width_s: float) -> np.ndarray:
    """Bin-integrated Gaussian of FWHM ``pulse_width_s``, truncated at 5 sigma, unit sum."""
    sigma = pulse_width_s / (2 * math.sqrt(2 * math.log(2))) / bin_width_s
    K = max(1, int(math.ceil(5 * sigma)))
    edges = (np.arange(-K, K + 2) - 0.5) / (sigma * math.sqrt(2))
    taps = np.diff(erf(edges)) / 2
    return taps / taps.sum()


class PulseBlur(LinearOperator):
    """Plan: the pulse blur on transients of ``shape`` [t, ...] (see module docstring)."""

    name = "pulse_blur"

    def __init__(self, shape, pulse_width_s, bin_width_s, dtype=np.float32, queue=None):
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        self.shape = self.in_shape = self.out_shape = tuple(int(s) for s in shape)
        taps = pulse_taps(pulse_width_s, bin_width_s)
        self.K = (len(taps) - 1) // 2
        self.taps = cla.to_device(self.queue, taps.astype(self.dtype))
        self.taps_reversed = cla.to_device(self.queue, taps[::-1].astype(self.dtype))
        self._k = get_kernels(self.queue, "temporal", real_defines(self.dtype))

    def _convolve(self, x: cla.Array, taps: cla.Array) -> cla.Array:
        nt = self.shape[0]
        n_scan = int(np.prod(self.shape[1:]))
        out = cla.empty_like(x)
        self._k.time_convolve(self.queue, (round_up(n_scan, 64), nt), None, x.data, out.data,
                              taps.data, kernel_int(self.K), kernel_int(nt, "time bins"),
                              kernel_int(n_scan, "scan points"))
        return out

    def _apply(self, x):
        return self._convolve(x, self.taps)

    def _adjoint(self, y):
        return self._convolve(y, self.taps_reversed)

    def __call__(self, x):
        if isinstance(x, cla.Array) and tuple(x.shape) == self.shape:
            return self._apply(x)  # device arrays of any dtype-compatible buffer, as before
        return super().__call__(x)

"""FFT-grid helpers shared by the blur, diffusion and light-cone stages (pure numpy)."""

from __future__ import annotations

import numpy as np


def grid_offsets(n: int, pitch_m: float) -> np.ndarray:
    """Offsets of an FFT grid of n cells in wrap order: 0, p, 2p, ..., -2p, -p (m).

    Index 0 is zero offset (no half-cell shift); index j >= ceil(n/2) is offset (j - n) p.
    """
    j = np.arange(n)
    return np.where(j < (n + 1) // 2, j, j - n) * float(pitch_m)


def fast_length(n: int) -> int:
    """The smallest 5-smooth number (factors 2, 3 and 5 only) >= n: an FFT length pocketfft
    and VkFFT factor well."""
    m = max(1, int(n))
    while True:
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


def padded_length(n: int) -> int:
    """Time length of the zero-padded grid of a convolution or Wiener filter of n bins: the
    smallest even :func:`fast_length` >= 2 n -- twice the data, so a kernel of up to n lags
    does not wrap, rounded up to a length the FFTs factor well (2 x 709 bins, a tail-filled
    window, sent pocketfft to Bluestein's algorithm: 3.7x the time of the 1440 this gives
    along that axis)."""
    m = fast_length(2 * max(1, int(n)))
    while m % 2:
        m = fast_length(m + 1)
    return m


BLOCK_VALUES = 1 << 20  # values per block of a host pass over a large array (8 MB float64)


def row_blocks(shape, values: int = BLOCK_VALUES) -> list[tuple[int, int]]:
    """(r0, r1) blocks of the first axis of an array of ``shape`` holding about ``values``
    elements each: host passes over a grid-sized array with bounded temporaries."""
    n0 = int(shape[0])
    step = max(1, values // max(1, int(np.prod(shape[1:]))))
    return [(r0, min(n0, r0 + step)) for r0 in range(0, n0, step)]


def block_sums(transient: np.ndarray, f: int) -> np.ndarray:
    """A capture [t, y, x] with its scan points summed over f x f blocks (counts stay
    counts: a sum of Poisson counts is Poisson); f divides both scan sides."""
    if f == 1:
        return np.asarray(transient)
    t, ny, nx = transient.shape
    a = np.asarray(transient)
    return a.reshape(t, ny // f, f, nx // f, f).sum(axis=(2, 4), dtype=a.dtype)


def grid_label(shape) -> str:
    """A grid's shape as the params record it: "512x64x64"."""
    return "x".join(str(int(v)) for v in shape)

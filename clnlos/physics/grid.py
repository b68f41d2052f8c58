"""FFT-grid helpers shared by the blur, diffusion and light-cone stages (pure numpy)."""

from __future__ import annotations

import numpy as np


def grid_offsets(n: int, pitch_m: float) -> np.ndarray:
    """Offsets of an FFT grid of n cells in wrap order: 0, p, 2p, ..., -2p, -p (m).

    Index 0 is zero offset (no half-cell shift); index j >= ceil(n/2) is offset (j - n) p.
    """
    j = np.arange(n)
    return np.where(j < (n + 1) // 2, j, j - n) * float(pitch_m)

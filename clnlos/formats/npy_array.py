"""A plain NumPy array [t, y, x] (``.npy``): the bin width and the scan width are not in the
file and come from ``--bin-width`` / ``--scan-width`` (or the [capture] table); bin 0 starts
at t = 0 unless ``start_s`` is given."""

from __future__ import annotations

import numpy as np

from ..errors import InputFileError
from ..io import Capture
from .common import validate_transient


def read_npy(path) -> Capture:
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{path}: not a readable .npy array ({exc})") from None
    return Capture(validate_transient(arr, path), None, 0.0, None, str(path),
                   {"format": "npy"})

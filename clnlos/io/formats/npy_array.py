"""A plain NumPy array [t, y, x] (``.npy``): the bin width and the scan width are not in the
file and come from ``--bin-width`` / ``--scan-width`` (or the [capture] table); bin 0 starts
at t = 0 unless ``start_s`` is given."""

from __future__ import annotations

import numpy as np
from numpy.lib import format as npy

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.formats.common import validate_transient
from clnlos.runtime.limits import declared_capture


def _declared_npy(path) -> None:
    """Declare the array's size from the .npy header before the data are loaded; a header
    numpy cannot parse is left to :func:`read_npy`."""
    try:
        with open(path, "rb") as f:
            version = npy.read_magic(f)
            read = npy.read_array_header_1_0 if version == (1, 0) else \
                npy.read_array_header_2_0
            shape, _, dtype = read(f)
    except (OSError, ValueError, SyntaxError):
        return
    if len(shape) == 3:
        declared_capture(path, shape, dtype.itemsize)


def read_npy(path) -> Capture:
    _declared_npy(path)
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{path}: not a readable .npy array ({exc})") from None
    return Capture(validate_transient(arr, path), None, 0.0, None, str(path),
                   {"format": "npy"})

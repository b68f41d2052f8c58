"""A plain NumPy array (``.npy``): no layout, bin width or scan width is in the file. The array
is read with the layout given (``--axes``, :mod:`clnlos.io.layout`), else the one assumed
from its shape, named in a note (:func:`clnlos.io.layout.assumed_layout`: [t, y, x] unless
another axis is longer than the first); the bin width and the scan width come from
``--bin-width`` / ``--scan-width`` (or the [capture] table); bin 0 starts at t = 0 unless
``start_s`` is given."""

from __future__ import annotations

import numpy as np
from numpy.lib import format as npy

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.formats.common import array_capture, validate_transient
from clnlos.io.layout import Layout, assumed_layout
from clnlos.runtime.limits import declared_capture


def _declared_npy(path, axes: Layout | None) -> None:
    """Declare the array's size (as [t, y, x] in the layout it will be read with) from the
    .npy header before the data are loaded; a header numpy cannot parse is left to
    :func:`read_npy`."""
    try:
        with open(path, "rb") as f:
            version = npy.read_magic(f)
            read = npy.read_array_header_1_0 if version == (1, 0) else \
                npy.read_array_header_2_0
            shape, _, dtype = read(f)
    except (OSError, ValueError, SyntaxError):
        return
    if len(shape) == 3:
        declared_capture(path, (axes or assumed_layout(shape)).shape_tyx(shape),
                         dtype.itemsize)


def read_npy(path, axes: Layout | None = None) -> Capture:
    _declared_npy(path, axes)
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{path}: not a readable .npy array ({exc})") from None
    if arr.ndim != 3:
        validate_transient(arr, path)  # the error names the shape
    return array_capture(arr, path, given=axes, what="the array", fmt="npy", order=arr.shape)

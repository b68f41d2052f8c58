"""Helpers shared by the capture readers: validation, layouts, per-pixel time alignment."""

from __future__ import annotations

import h5py
import numpy as np

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.layout import Layout, assumed_layout
from clnlos.runtime.limits import declared_capture

# why a layout was taken for an array that records none (the note names it)
ASSUMED_LAYOUT = ("assumed, no layout recorded: time on the longest axis, the scan axes as "
                  "rows then columns")


def validate_transient(arr, path) -> np.ndarray:
    """A finite, non-negative float32 [t, y, x] array, else a one-line InputFileError."""
    arr = np.asarray(arr)
    if arr.ndim != 3:
        raise InputFileError(f"{path}: transient must be 3D [t, y, x], got shape {arr.shape}")
    if min(arr.shape) < 1:
        raise InputFileError(f"{path}: transient is empty, shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise InputFileError(f"{path}: transient must be real numbers, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, np.float32)
    if not np.all(np.isfinite(arr)):
        raise InputFileError(f"{path}: transient holds NaN or Inf values")
    if np.any(arr < 0):
        raise InputFileError(f"{path}: transient holds negative counts (min {arr.min():.3g})")
    return arr


def declared_dataset(ds, path, *, order=(0, 1, 2), bin_width_s=None, start_s=0.0) -> None:
    """Check an HDF5 dataset's declared shape and dtype before it is read
    (:func:`clnlos.runtime.limits.declared_capture`); ``order``: the dataset's axes that become
    [t, y, x]. A dataset that is not 3D or not numeric (or a group) is left to the reader's
    own checks."""
    if not isinstance(ds, h5py.Dataset):
        return
    shape = ds.shape
    if shape is None or len(shape) != len(order) or ds.dtype.kind not in "biuf":
        return
    declared_capture(path, [shape[a] for a in order], ds.dtype.itemsize,
                     bin_width_s=bin_width_s, start_s=start_s)


def shift_earlier(arr: np.ndarray, shift_bins: np.ndarray) -> np.ndarray:
    """Move each column of [t, y, x] earlier by ``shift_bins[y, x]`` (>= 0, fractional) bins.

    The histogram of each column is shifted and re-binned by bin overlaps (a fractional shift
    f splits each bin between two neighbours with weights 1 - f and f), so counts are
    conserved except those moved before bin 0; bins past the end are filled with 0.
    """
    nt = arr.shape[0]
    s = np.asarray(shift_bins, np.float64)
    if s.shape != arr.shape[1:] or np.any(~np.isfinite(s)) or np.any(s < 0):
        raise InputFileError("time offsets must be finite, >= 0 and one per scan point")
    s = np.minimum(s, nt)  # a shift past the window's end empties the column (no overflow)
    k0 = np.floor(s).astype(np.int64)
    f = s - k0
    t = np.arange(nt)[:, None, None]
    out = np.zeros(arr.shape, np.float64)
    for off, w in ((k0, 1.0 - f), (k0 + 1, f)):
        src = t + off[None]
        ok = src < nt
        vals = np.take_along_axis(arr, np.minimum(src, nt - 1), axis=0)
        out += np.where(ok, vals, 0.0) * w[None]
    return out.astype(np.float32)


def align_columns(arr: np.ndarray, shift_bins: np.ndarray, path, what: str
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(the columns moved earlier by ``shift_bins`` [y, x] (:func:`shift_earlier`) and cut
    to the bins every scan point recorded, the shifts): a column moved by s bins holds no
    data past nt - s, and zeros there would read as "no light", so the window ends at
    nt - max(s). ``what`` names the offsets in the error when no bin is left."""
    s = np.asarray(shift_bins, np.float64)
    out = shift_earlier(arr, s)
    keep = int(np.floor(arr.shape[0] - s.max() + 1e-9)) if s.size else arr.shape[0]
    if keep < 1:
        raise InputFileError(f"{path}: {what} moves a scan point's data {s.max():.4g} bins "
                             f"earlier, past the {arr.shape[0]}-bin window: no bin is left "
                             "that every scan point recorded")
    return out[:keep], s


def recorded_layout(layout: Layout, given: bool, what: str, stored_shape, why: str) -> dict:
    """The attributes a reader records of the layout it read ``what`` (the array's name)
    with: ``axes`` (its text), ``axes_source`` ("given", else ``why``), ``axes_array`` and
    ``axes_stored_shape`` (for the reconstruction's note and the output's record)."""
    return {"axes": str(layout), "axes_source": "given" if given else why,
            "axes_array": what, "axes_stored_shape": [int(n) for n in stored_shape]}


def array_capture(stored, path, *, given: Layout | None, what: str, fmt: str,
                  order, matlab73: bool = False) -> Capture:
    """A Capture of one 3-D array of a file that records no layout: read with the layout
    ``given``, else :func:`clnlos.io.layout.assumed_layout` of ``order`` (the stored shape in
    the order the layout names: MATLAB's for a .mat); no bin width, scan width or start is
    taken (bin 0 at t = 0). An h5py dataset is declared before it is read
    (:func:`clnlos.runtime.limits.declared_capture`); ``matlab73``: its axes are MATLAB's
    reversed."""
    order = tuple(int(n) for n in order)
    layout = given if given is not None else assumed_layout(order)
    if isinstance(stored, h5py.Dataset):
        declared_capture(path, layout.shape_tyx(order), stored.dtype.itemsize)
        try:
            stored = stored[()]
        except (OSError, ValueError) as exc:
            raise InputFileError(f"{path}: cannot read {what} ({exc})") from None
        if matlab73:
            stored = np.transpose(stored)
    arr = validate_transient(layout.to_tyx(stored), path)
    attrs = {"format": fmt, **recorded_layout(layout, given is not None, what, order,
                                              ASSUMED_LAYOUT)}
    return Capture(arr, None, 0.0, None, str(path), attrs)

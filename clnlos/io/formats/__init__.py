"""Capture readers, one module per format family behind :func:`read_capture` (chosen by the
file's content, never its extension), and the y-tal writer.

Every reader returns the one in-memory contract :class:`clnlos.io.capture.Capture`: transient
[t, y, x] (x increasing with the column index, y with the row index, as seen from the scan
plane looking into the hidden volume), bin width and start of bin 0 (s, round trip from the
scan plane), scan width (m; None where the file does not say), and the file's own attributes.

==============================  ====================================  ==================
format                          recognised by                         module
==============================  ====================================  ==================
clnlos HDF5                     HDF5 with dataset ``transient``       :mod:`.clnlos_h5`
y-tal HDF5 (Zaragoza NLOS)      HDF5 with datasets ``H``, ``H_format``  :mod:`.tal`
MATLAB v7.3 (CDT, LCT, f-k,     the "MATLAB 7.3 MAT-file" header       :mod:`.mat`
one 3-D array of any name)      before the HDF5 at byte 512
MATLAB v5/v7 (the same)         "MATLAB 5.0 MAT-file" header          :mod:`.mat`
HDF5 of another tool            HDF5 with one 3-D numeric dataset     :mod:`.common`
NumPy array                     ``.npy`` magic                        :mod:`.npy_array`
==============================  ====================================  ==================

An HDF5 file without MATLAB's header holding ``meas`` or ``rect_data`` is read as the MATLAB
layouts (as MATLAB v7.3 writes them, axes reversed). The formats that record their layout
(clnlos, y-tal) refuse a layout given (``axes``); every other array is read with the layout
given or the one its layout's published code displays or, for an array of no known layout,
the one assumed from its shape (:mod:`clnlos.io.layout`), recorded in the capture's
attributes (``axes``, ``axes_source``) for the reconstruction's note.
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.formats.clnlos_h5 import read_clnlos
from clnlos.io.formats.common import array_capture
from clnlos.io.formats.mat import one_array, read_mat5, read_mat73
from clnlos.io.formats.npy_array import read_npy
from clnlos.io.formats.tal import read_tal
from clnlos.io.layout import Layout, parse_axes

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
NPY_MAGIC = b"\x93NUMPY"
MAT5_MAGIC = b"MATLAB 5.0 MAT-file"
MAT73_MAGIC = b"MATLAB 7.3 MAT-file"  # the text of the user block before a v7.3 file's HDF5
MAT73_HDF5_AT = 512  # ... which starts at this byte


def sniff(path: Path) -> str:
    """"mat73", "hdf5", "npy" or "mat5" from the first bytes (MATLAB v7.3: its header text,
    then HDF5 at byte MAT73_HDF5_AT)."""
    try:
        with open(path, "rb") as f:
            head = f.read(520)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot be read ({exc.strerror})") from None
    if head[MAT73_HDF5_AT:MAT73_HDF5_AT + 8] == HDF5_MAGIC and head.startswith(MAT73_MAGIC):
        return "mat73"
    if head.startswith(HDF5_MAGIC) or head[MAT73_HDF5_AT:MAT73_HDF5_AT + 8] == HDF5_MAGIC:
        return "hdf5"
    if head.startswith(NPY_MAGIC):
        return "npy"
    if head.startswith(MAT5_MAGIC):
        return "mat5"
    raise InputFileError(f"{path}: not a capture file clnlos reads (clnlos or y-tal HDF5, "
                         "MATLAB .mat v5/v7/v7.3, NumPy .npy)")


def read_capture(path: str | os.PathLike, axes: str | Layout | None = None) -> Capture:
    """Read a capture of any supported format (see the module docstring); ``axes``: the
    layout of a stored array that records none (:func:`clnlos.io.layout.parse_axes`)."""
    path = Path(path)
    layout = None if axes is None else parse_axes(axes)
    if not path.is_file():
        raise InputFileError(f"{path}: no such file" if not path.exists() else
                             f"{path}: not a file")
    kind = sniff(path)
    if kind == "npy":
        return read_npy(path, layout)
    if kind == "mat5":
        return read_mat5(path, layout)
    return _read_hdf5(path, layout, matlab=kind == "mat73")


def _read_hdf5(path: Path, layout: Layout | None, *, matlab: bool) -> Capture:
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(f"{path}: not a readable HDF5/MATLAB v7.3 file ({exc})") from None
    try:
        with f:
            keys = set(f.keys())
            if matlab or "meas" in keys or "rect_data" in keys:
                return read_mat73(f, path, layout)
            if "transient" in keys:
                _recorded(path, layout, "a clnlos capture: [t, y, x]")
                return read_clnlos(f, path)
            if {"H", "H_format"} <= keys:
                _recorded(path, layout, "y-tal: its H_format")
                return read_tal(f, path)
            name, ds = one_array(hdf5_arrays(f), path, "dataset")
            return array_capture(ds, path, given=layout, what=f"dataset {name!r}",
                                 fmt="hdf5-array", order=ds.shape)
    except InputFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise InputFileError(f"{path}: unreadable ({exc})") from None


def _recorded(path: Path, layout: Layout | None, which: str) -> None:
    """A format that records its layout refuses another one given."""
    if layout is not None:
        raise InputFileError(f"{path}: records its layout ({which}); a layout given (axes "
                             f"{layout}) is for arrays stored without one (.npy, .mat, HDF5 "
                             "of other tools)")


def hdf5_arrays(f) -> dict:
    """Every numeric 3-D dataset of an HDF5 file, by its path."""
    found = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset) and len(obj.shape or ()) == 3 \
                and obj.dtype.kind in "biuf":
            found[name] = obj

    f.visititems(visit)
    return found


__all__ = ["read_capture", "sniff"]

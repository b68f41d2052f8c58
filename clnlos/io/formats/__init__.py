"""Capture readers, one module per format family behind :func:`read_capture` (chosen by the
file's content, never its extension), and the y-tal writer.

Every reader returns the one in-memory contract :class:`clnlos.io.capture.Capture`: transient
[t, y, x] (x increasing with the column index, y with the row index, as seen from the scan
plane looking into the hidden volume), bin width and start of bin 0 (s, round trip from the
scan plane), scan width (m; None where the file does not say), and the file's own attributes.

============================  ======================================  ======================
format                        recognised by                           module
============================  ======================================  ======================
clnlos HDF5                   HDF5 with dataset ``transient``         :mod:`.clnlos_h5`
y-tal HDF5 (Zaragoza NLOS)    HDF5 with datasets ``H``, ``H_format``  :mod:`.tal`
CDT MATLAB v7.3               HDF5 (MAT 7.3) with ``meas``            :mod:`.mat`
MATLAB v5/v7 (CDT, LCT, f-k)  "MATLAB 5.0 MAT-file" header            :mod:`.mat`
NumPy array [t, y, x]         ``.npy`` magic; bin and scan width      :mod:`.npy_array`
                              from --bin-width / --scan-width
============================  ======================================  ======================
"""

from __future__ import annotations

import os
from pathlib import Path

import h5py

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.formats.clnlos_h5 import read_clnlos
from clnlos.io.formats.mat import read_mat5, read_mat73
from clnlos.io.formats.npy_array import read_npy
from clnlos.io.formats.tal import read_tal

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
NPY_MAGIC = b"\x93NUMPY"
MAT5_MAGIC = b"MATLAB 5.0 MAT-file"


def sniff(path: Path) -> str:
    """"hdf5", "npy" or "mat5" from the first bytes (HDF5 may sit at 512, MATLAB 7.3)."""
    try:
        with open(path, "rb") as f:
            head = f.read(520)
    except OSError as exc:
        raise InputFileError(f"{path}: cannot be read ({exc.strerror})") from None
    if head.startswith(HDF5_MAGIC) or head[512:520] == HDF5_MAGIC:
        return "hdf5"
    if head.startswith(NPY_MAGIC):
        return "npy"
    if head.startswith(MAT5_MAGIC):
        return "mat5"
    raise InputFileError(f"{path}: not a capture file clnlos reads (clnlos or y-tal HDF5, "
                         "MATLAB .mat v5/v7/v7.3, NumPy .npy)")


def read_capture(path: str | os.PathLike) -> Capture:
    """Read a capture of any supported format (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such file" if not path.exists() else
                             f"{path}: not a file")
    kind = sniff(path)
    if kind == "npy":
        return read_npy(path)
    if kind == "mat5":
        return read_mat5(path)
    return _read_hdf5(path)


def _read_hdf5(path: Path) -> Capture:
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(f"{path}: not a readable HDF5/MATLAB v7.3 file ({exc})") from None
    try:
        with f:
            keys = set(f.keys())
            if "transient" in keys:
                return read_clnlos(f, path)
            if {"H", "H_format"} <= keys:
                return read_tal(f, path)
            if "meas" in keys or "rect_data" in keys:
                return read_mat73(f, path)
            raise InputFileError(f"{path}: no dataset 'transient' (clnlos), 'H' (y-tal), "
                                 f"'meas' or 'rect_data' (MATLAB); found {sorted(keys)}")
    except InputFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise InputFileError(f"{path}: unreadable ({exc})") from None


__all__ = ["read_capture", "sniff"]

"""Reading captures (any format, :mod:`clnlos.io.formats`) and writing results (HDF5, PNG).

Every output is written to a temporary file in the target folder and renamed into place, so
an interrupted or failed run leaves nothing half-written.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from pathlib import Path

import h5py
import numpy as np

from clnlos.errors import InputFileError
from clnlos.io.capture import CAPTURE_FORMAT, Capture, plain_attr
from clnlos.io.deflate import write_dataset
from clnlos.io.figures import close_figure
from clnlos.io.formats import read_capture as read
from clnlos.io.outputs import png_metadata, write_group


def read_capture(path: str | os.PathLike, axes: str | None = None) -> Capture:
    """Read a capture of any supported format (:func:`clnlos.io.formats.read_capture`;
    ``axes``: the layout of an array that records none, :mod:`clnlos.io.layout`)."""
    return read(path, axes)




def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes (hex), read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; rename it onto ``path`` (with the mode the
    umask gives a new file) only on success."""
    with write_group([Path(path)]) as (tmp,):
        yield tmp


def _attr_value(v):
    if v is None:
        return "none"
    if isinstance(v, dict | list | tuple):
        return json.dumps(v)
    return v


def write_h5_file(path, datasets: dict, attrs: dict) -> Path:
    """Write datasets (arrays, or :class:`clnlos.io.deflate.DeflatedArray` already being
    compressed) and file attributes to ``path`` (not atomic: see write_h5); gzip + shuffle,
    large arrays compressed in parallel (:mod:`clnlos.io.deflate`)."""
    with h5py.File(path, "w") as f:
        for name, arr in datasets.items():
            write_dataset(f, name, arr)
        for k, v in attrs.items():
            f.attrs[k] = _attr_value(v)
    return Path(path)


def write_h5(path, datasets: dict[str, np.ndarray], attrs: dict) -> Path:
    """Write datasets and file attributes to ``path`` atomically."""
    with atomic_path(path) as tmp:
        write_h5_file(tmp, datasets, attrs)
    return Path(path)


def capture_attrs(*, bin_width_s: float, start_s: float, scan_width_m: float,
                  attrs: dict | None = None, shape=None,
                  scan_center_m=(0.0, 0.0)) -> dict:
    """Attributes of the clnlos capture format (see clnlos.io.formats.clnlos_h5):
    ``scan_width_m`` is the side along x (columns); with the transient's ``shape`` of a
    non-square scan the side along y is recorded too (``scan_height_m``)."""
    a = {"bin_width_s": float(bin_width_s), "start_s": float(start_s),
         "scan_width_m": float(scan_width_m), "format": CAPTURE_FORMAT}
    if shape is not None and int(shape[1]) != int(shape[2]):  # a square scan: implied
        a["scan_height_m"] = float(scan_width_m) * int(shape[1]) / int(shape[2])
    if any(scan_center_m):
        a["scan_center_m"] = [float(v) for v in scan_center_m]
    a.update(attrs or {})
    return a


def write_capture(path, transient: np.ndarray, *, bin_width_s: float, start_s: float,
                  scan_width_m: float, attrs: dict | None = None,
                  scan_center_m=(0.0, 0.0)) -> Path:
    """Write the clnlos capture format atomically (``scan_width_m``: the side along x)."""
    arr = np.asarray(transient, np.float32)
    return write_h5(path, {"transient": arr},
                    capture_attrs(bin_width_s=bin_width_s, start_s=start_s,
                                  scan_width_m=scan_width_m, attrs=attrs, shape=arr.shape,
                                  scan_center_m=scan_center_m))


def save_figure_file(fig, path) -> Path:
    """Save a figure (matplotlib, or :class:`clnlos.io.raster.RasterFigure`) as PNG to
    ``path``, marked as clnlos's (:func:`clnlos.io.outputs.png_metadata`), and close it (not
    atomic)."""
    fig.savefig(path, format="png", dpi=110, bbox_inches="tight", metadata=png_metadata())
    close_figure(fig)
    return Path(path)


def save_figure(fig, path) -> Path:
    """Save a matplotlib figure to PNG atomically and close it."""
    with atomic_path(path) as tmp:
        save_figure_file(fig, tmp)
    return Path(path)


def read_volume(path) -> tuple[np.ndarray, dict, dict]:
    """(volume [z, y, x], extents, attributes) of a volume file written by reconstruct."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such file")
    keys = ("depth_min_m", "depth_max_m", "voxel_depth_m", "x_min_m", "x_max_m", "y_min_m",
            "y_max_m", "voxel_lateral_m")
    try:
        with h5py.File(path, "r") as f:
            if "volume" not in f:
                raise InputFileError(f"{path}: no dataset 'volume' (not a clnlos volume file)")
            vol = np.asarray(f["volume"][()], np.float32)
            attrs = {k: plain_attr(v) for k, v in f.attrs.items()}
    except OSError as exc:
        raise InputFileError(f"{path}: not a readable HDF5 file ({exc})") from None
    missing = [k for k in keys if k not in attrs]
    if vol.ndim != 3 or missing:
        raise InputFileError(f"{path}: a volume [z, y, x] with its extents is needed "
                             f"(missing {', '.join(missing) or 'a 3D volume'})")
    return vol, {k: float(attrs[k]) for k in keys}, attrs

"""clnlos HDF5 captures (written by ``clnlos simulate``): dataset ``transient`` float32
[t, y, x] with x and y increasing with index; attributes ``bin_width_s``, ``start_s`` (time of
the start of bin 0, round trip from the scan plane), ``scan_width_m`` (the side along x),
``scan_height_m`` (along y; a non-square scan without it leaves the pitch to --scan-width),
``scan_center_m`` (x, y of the grid's centre; default 0, 0), ``format`` (clnlos-capture-1)
and the recorded setup (``scene``, ``slab``, ``stages``, ``pulse_width_s``,
``clnlos_version``)."""

from __future__ import annotations

import json

import h5py
import numpy as np

from clnlos.errors import InputFileError
from clnlos.io.capture import CAPTURE_FORMAT, Capture, plain_attr
from clnlos.io.formats.common import declared_dataset, validate_transient


def read_clnlos(f, path) -> Capture:
    ds = f["transient"]
    if not isinstance(ds, h5py.Dataset):
        raise InputFileError(f"{path}: 'transient' is an HDF5 {type(ds).__name__.lower()}, "
                             "not a dataset (a clnlos capture stores the transient [t, y, x] "
                             "as one dataset)")
    at = dict(ds.attrs) | dict(f.attrs)

    def num(name, required):
        if name not in at:
            if required:
                raise InputFileError(f"{path}: attribute {name!r} missing")
            return None
        try:
            v = float(np.asarray(at[name]).reshape(()))
        except (TypeError, ValueError):
            raise InputFileError(f"{path}: attribute {name!r} is not a number") from None
        if not np.isfinite(v):
            raise InputFileError(f"{path}: attribute {name!r} = {v} is not finite")
        return v

    fmt = plain_attr(at.get("format", CAPTURE_FORMAT))
    if fmt != CAPTURE_FORMAT:
        raise InputFileError(f"{path}: attribute 'format' = {fmt!r}: this clnlos reads "
                             f"{CAPTURE_FORMAT!r} captures")
    bin_width, start = num("bin_width_s", True), num("start_s", False) or 0.0
    declared_dataset(ds, path, bin_width_s=bin_width, start_s=start)  # before reading it
    try:
        arr = validate_transient(ds[()], path)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{path}: cannot read dataset 'transient' ({exc})") from None
    attrs = {k: plain_attr(v) for k, v in at.items()}
    width, height = num("scan_width_m", False), num("scan_height_m", False)
    ny, nx = arr.shape[1:]
    if width is not None and height is None and ny != nx:
        # one side of a non-square scan: which axis it measures is not recorded
        attrs["scan_width_unknown"] = (f"{path} records one scan_width_m = {width:g} m for a "
                                       f"{ny} x {nx} [y, x] scan (not square) and not which "
                                       "side it measures")
        width = None
    return Capture(arr, bin_width, start, width, str(path), attrs,
                   scan_center_m=_center(at, path), scan_height_m=height)


def _center(at: dict, path) -> tuple[float, float]:
    """(x, y) of attribute ``scan_center_m`` (m), (0, 0) when absent."""
    if "scan_center_m" not in at:
        return (0.0, 0.0)
    raw = plain_attr(at["scan_center_m"])
    try:
        c = np.asarray(json.loads(raw) if isinstance(raw, str) else raw,
                       np.float64).reshape(2)
    except (TypeError, ValueError):
        raise InputFileError(f"{path}: attribute 'scan_center_m' must be two numbers (x, y) "
                             "in m") from None
    if not np.all(np.isfinite(c)):
        raise InputFileError(f"{path}: attribute 'scan_center_m' = {c.tolist()} is not finite")
    return float(c[0]), float(c[1])

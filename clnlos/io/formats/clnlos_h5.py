"""clnlos HDF5 captures (written by ``clnlos simulate``): dataset ``transient`` float32
[t, y, x] with x and y increasing with index; attributes ``bin_width_s``, ``start_s`` (time of
the start of bin 0, round trip from the scan plane), ``scan_width_m`` and the recorded setup
(``scene``, ``slab``, ``stages``, ``pulse_width_s``, ``clnlos_version``)."""

from __future__ import annotations

import numpy as np

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture, plain_attr
from clnlos.io.formats.common import declared_dataset, validate_transient


def read_clnlos(f, path) -> Capture:
    ds = f["transient"]
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

    bin_width, start = num("bin_width_s", True), num("start_s", False) or 0.0
    declared_dataset(ds, path, bin_width_s=bin_width, start_s=start)  # before reading it
    try:
        arr = validate_transient(ds[()], path)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{path}: cannot read dataset 'transient' ({exc})") from None
    return Capture(arr, bin_width, start, num("scan_width_m", False), str(path),
                   {k: plain_attr(v) for k, v in at.items()})

"""MATLAB captures: v7.3 (HDF5, read with h5py) and v5/v7 (read with scipy.io.loadmat).

Layouts, told apart by their variables (MATLAB index order (i, j, k) = numpy order of
``loadmat``; h5py reverses it):

* CDT (Lindell & Wetzstein 2020): ``meas`` of MATLAB size (T, N, N) = (t, y running down,
  x), 16 ps bins (``CDT_MAT_BIN_WIDTH_S``), bin 0 at t = 0; the scan width is not stored.
  Checked on the published letters: they read "UT", U on the left.
* LCT (O'Toole, Lindell & Wetzstein 2018): ``rect_data`` of size (N, N, T) and ``width`` =
  half the scan width (m), as released with the paper; ``bin_resolution`` (s) where a file
  has it, else the published code's 4 ps (``LCT_MAT_BIN_WIDTH_S``). Orientation as the
  published code (``cnlos_reconstruction.m``) displays it: it permutes the data to (t, j, i),
  reverses i, and shows the front view with j running down the image. So index j runs down
  (-y) and index i runs right to left (-x): [t, y, x] = rect_data[::-1, ::-1, :] transposed
  to (t, j, i); the letters of the released captures then read left to right, seen from the
  wall. The window starts at the direct reflection off the wall ("pre-rectified"); its
  first ``LCT_DIRECT_END_S`` (the 600 bins of 4 ps the published code zeroes) are recorded
  as the direct reflection (attribute ``direct_end_s``), which a reconstruction removes
  (:func:`clnlos.io.capture.without_direct`).
* f-k (Lindell, Wetzstein & O'Toole 2019): ``meas`` of size (N, N, T) = (y, x, t) and
  ``tofgrid`` (N, N), the time of flight (ps) from the laser and detector to each scan
  point. The published code (``cnlos_reconstruction.m`` of nlos-fk) shows the front view as
  ``meas``'s first index running down the image and its second to the right (it reverses
  both and labels both axes from +w to -w, which ``imagesc`` draws back the same way), so
  row i is y = -i: [t, y, x] = meas[::-1, :, :] transposed. The time of flight is removed (each column moved earlier by it, fractionally, counts
  conserved); 32 ps bins (the published code's ``bin_resolution``), scan width not stored.
  A ``meas`` of size (N, N, T) without ``tofgrid`` is read the same way, already aligned.
"""

from __future__ import annotations

import struct

import h5py
import numpy as np
import scipy.io

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.formats.common import align_columns, declared_dataset, validate_transient
from clnlos.runtime.limits import declared_capture

CDT_MAT_BIN_WIDTH_S = 16e-12  # the CDT capture format's histogram bin
FK_MAT_BIN_WIDTH_S = 32e-12   # bin_resolution of the f-k data files
LCT_MAT_BIN_WIDTH_S = 4e-12   # the LCT release's SPAD bin (cnlos_reconstruction.m)
LCT_DIRECT_END_S = 600 * LCT_MAT_BIN_WIDTH_S  # the direct reflection the published code zeroes
LCT_RELEASE_BIN_WIDTH_S = 16e-12  # ... and its time bin (4 ps summed in fours, K = 2)
LCT_RELEASE_REFLECTANCE = "retroreflective"  # its published default: (t/T)^2
DIRECT_PEAK_FRACTION = 0.02   # a direct reflection peaks within this fraction of the window
DIRECT_PEAK_OVER_MEDIAN = 10.0  # ... this many times above the window's median


def _scalar(v, name, path) -> float:
    try:
        x = float(np.asarray(v, np.float64).reshape(()))
    except (TypeError, ValueError):
        raise InputFileError(f"{path}: variable {name!r} must be a number") from None
    if not np.isfinite(x) or x <= 0:
        raise InputFileError(f"{path}: variable {name!r} = {x} must be > 0 and finite")
    return x


def _time_last(meas, path, name) -> bool:
    if meas.ndim != 3:
        raise InputFileError(f"{path}: {name!r} must be 3D, got shape {meas.shape}")
    return meas.shape[2] > max(meas.shape[0], meas.shape[1])


def from_lct(rect_data, width, bin_resolution, path) -> Capture:
    """The LCT layout (module docstring): ``bin_resolution`` None takes the published 4 ps,
    recorded in the attributes (``bin_width_source``) for the reconstruction's note."""
    if rect_data.ndim != 3:
        raise InputFileError(f"{path}: 'rect_data' must be 3D (N, N, T), got {rect_data.shape}")
    arr = validate_transient(np.transpose(rect_data[::-1, ::-1, :], (2, 1, 0)), path)
    attrs = {"format": "lct-mat", "reflectance_default": LCT_RELEASE_REFLECTANCE,
             "reflectance_source": "the published code's default for this release (isdiffuse"
                                   " = 0: retroreflective targets, 1/r^2)",
             "bin_width_default_s": LCT_RELEASE_BIN_WIDTH_S,
             "bin_width_default_source": "the published code sums the 4 ps bins in fours"}
    if starts_with_direct_reflection(arr):
        attrs["direct_end_s"] = LCT_DIRECT_END_S
    if bin_resolution is None:
        bin_width = LCT_MAT_BIN_WIDTH_S
        attrs["bin_width_source"] = ("the published code's 4 ps (cnlos_reconstruction.m); "
                                     "the file does not store it")
    else:
        bin_width = _scalar(bin_resolution, "bin_resolution", path)
    return Capture(arr, bin_width, 0.0, 2.0 * _scalar(width, "width", path), str(path), attrs)


def starts_with_direct_reflection(transient: np.ndarray) -> bool:
    """Whether the window starts at a direct reflection ("pre-rectified", as the LCT
    release): the scan's summed histogram peaks in the first DIRECT_PEAK_FRACTION of the
    bins, above DIRECT_PEAK_OVER_MEDIAN times its median."""
    h = np.asarray(transient, np.float64).reshape(transient.shape[0], -1).sum(axis=1)
    k = int(np.argmax(h))
    return (k < max(2, DIRECT_PEAK_FRACTION * h.size)
            and h[k] > DIRECT_PEAK_OVER_MEDIAN * max(float(np.median(h)), 0.0))


def lct_rect_data(transient: np.ndarray) -> np.ndarray:
    """[t, y, x] -> the LCT layout's ``rect_data`` (N, N, T): the inverse of
    :func:`from_lct`'s orientation (for writing test files and exchanging data)."""
    return np.transpose(np.asarray(transient), (2, 1, 0))[::-1, ::-1, :]


def from_fk(meas, tofgrid, path) -> Capture:
    """The f-k layout (module docstring): rows run down the published front view."""
    meas = np.asarray(meas)
    if meas.ndim != 3:
        raise InputFileError(f"{path}: 'meas' must be 3D (N, N, T), got {meas.shape}")
    arr = validate_transient(np.transpose(meas[::-1], (2, 0, 1)), path)
    attrs = {"format": "fk-mat"}
    shifts = None
    if tofgrid is not None:
        try:
            tof = np.asarray(tofgrid, np.float64)[::-1]  # rows as the transient's
        except (TypeError, ValueError):
            raise InputFileError(f"{path}: 'tofgrid' must be numbers (ps)") from None
        if tof.shape != arr.shape[1:]:
            raise InputFileError(f"{path}: 'tofgrid' must be {arr.shape[1:]} like the scan, "
                                 f"got {tof.shape}")
        window_ps = arr.shape[0] * FK_MAT_BIN_WIDTH_S * 1e12
        bad = ~(np.isfinite(tof) & (tof >= 0) & (tof < window_ps))
        if bad.any():
            v = float(tof[bad].flat[0])
            raise InputFileError(f"{path}: 'tofgrid' holds {v:g} ps: allowed 0 to below "
                                 f"{window_ps:g} ps (the capture's time window, "
                                 f"{arr.shape[0]} bins of {FK_MAT_BIN_WIDTH_S * 1e12:g} ps)")
        attrs["aligned_from_bins"] = arr.shape[0]
        arr, shifts = align_columns(arr, tof * 1e-12 / FK_MAT_BIN_WIDTH_S, path,
                                    "'tofgrid'")
        attrs["tofgrid_removed"] = True
    return Capture(arr, FK_MAT_BIN_WIDTH_S, 0.0, None, str(path), attrs,
                   time_shift_bins=shifts)


def from_cdt(meas_t_y_x, path) -> Capture:
    """(t, y running down, x) -> [t, y, x] with +y up."""
    arr = validate_transient(meas_t_y_x[:, ::-1, :], path)
    return Capture(arr, CDT_MAT_BIN_WIDTH_S, 0.0, None, str(path), {"format": "cdt-mat"})


def _declared_mat73(f, path) -> None:
    """Declare the capture variable's size before it is read (h5py's shape is MATLAB's
    reversed; the time axis as :func:`read_mat73` will take it)."""
    if "rect_data" in f:  # MATLAB (N, N, T)
        declared_dataset(f["rect_data"], path)
    elif isinstance(f.get("meas"), h5py.Dataset) and len(f["meas"].shape or ()) == 3:
        m = f["meas"].shape[::-1]  # MATLAB's order
        t_last = "tofgrid" in f or m[2] > max(m[0], m[1])  # as _time_last decides
        declared_dataset(f["meas"], path, order=(0, 1, 2) if t_last else (2, 1, 0),
                         bin_width_s=FK_MAT_BIN_WIDTH_S if t_last else CDT_MAT_BIN_WIDTH_S)


def read_mat73(f, path) -> Capture:
    """MATLAB v7.3 (h5py's axis order is MATLAB's reversed)."""
    _declared_mat73(f, path)
    try:
        if "rect_data" in f:
            bin_res = f["bin_resolution"][()] if "bin_resolution" in f else None
            return from_lct(np.transpose(f["rect_data"][()]), f["width"][()], bin_res, path)
        meas = np.transpose(f["meas"][()])  # back to MATLAB's order
    except KeyError as exc:
        raise InputFileError(f"{path}: missing variable {exc}") from None
    if "tofgrid" in f or _time_last(meas, path, "meas"):
        tof = np.transpose(f["tofgrid"][()]) if "tofgrid" in f else None
        return from_fk(meas, tof, path)
    return from_cdt(meas, path)


# bytes per value of MATLAB's numeric classes (whosmat); anything else counted as double
MAT_CLASS_BYTES = {"double": 8, "single": 4, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
                   "int32": 4, "uint32": 4, "int64": 8, "uint64": 8, "logical": 1}


def _declared_mat5(path) -> None:
    """Declare the capture variable's size from the file's variable headers
    (scipy.io.whosmat) before loadmat reads everything. A file whose headers cannot be
    listed is left to :func:`read_mat5`'s own error."""
    try:
        info = {name: (shape, cls) for name, shape, cls in scipy.io.whosmat(path)}
    except Exception:  # any failure is reported by loadmat below
        return
    name = "rect_data" if "rect_data" in info else "meas" if "meas" in info else None
    if name is None or len(info[name][0]) != 3:
        return
    shape, cls = info[name]
    t_last = name == "rect_data" or "tofgrid" in info or shape[2] > max(shape[0], shape[1])
    lct_bin = None if "bin_resolution" in info else LCT_MAT_BIN_WIDTH_S  # read with the data
    bin_width = (lct_bin if name == "rect_data" else FK_MAT_BIN_WIDTH_S if t_last
                 else CDT_MAT_BIN_WIDTH_S)
    tyx = ((shape[2], shape[1], shape[0]) if name == "rect_data"  # from_lct's transpose
           else (shape[2], shape[0], shape[1]) if t_last else shape)
    declared_capture(path, tyx,
                     MAT_CLASS_BYTES.get(cls, 8), bin_width_s=bin_width)


def read_mat5(path) -> Capture:
    _declared_mat5(path)
    try:
        d = scipy.io.loadmat(path)
    except (ValueError, TypeError, NotImplementedError, OSError, IndexError, KeyError,
            EOFError, OverflowError, AttributeError, struct.error) as exc:
        # a corrupt or truncated file ends in any of these inside scipy's parser
        raise InputFileError(f"{path}: not a readable MATLAB v5/v7 file ({exc})") from None
    if "rect_data" in d:
        if "width" not in d:
            raise InputFileError(f"{path}: LCT layout ('rect_data') without 'width' (half the "
                                 "scan width, m)")
        return from_lct(d["rect_data"], d["width"], d.get("bin_resolution"), path)
    if "meas" in d:
        meas = np.asarray(d["meas"])
        if "tofgrid" in d or _time_last(meas, path, "meas"):
            return from_fk(meas, d.get("tofgrid"), path)
        return from_cdt(meas, path)
    names = sorted(k for k in d if not k.startswith("__"))
    raise InputFileError(f"{path}: no 'meas' (CDT, f-k) or 'rect_data' (LCT) variable; "
                         f"found {names}")

"""MATLAB captures: v7.3 (HDF5 behind MATLAB's 512-byte header, read with h5py) and v5/v7
(read with scipy.io.loadmat).

Arrays are taken in MATLAB's index order (i, j, k): ``loadmat``'s numpy order; h5py returns a
v7.3 array with its axes reversed, which is turned back first. Layouts, told apart by their
variables; each reads its array with the layout below (``--axes`` names another one, in the
same MATLAB order: :mod:`clnlos.io.layout`), and each parameter a layout does not store is
taken from its published code and recorded (``bin_width_source``, ``start_source``,
``scan_width_source``: one note line when a reconstruction uses them):

* CDT (Lindell & Wetzstein 2020): ``meas`` of MATLAB size (T, N, N) = (t, y running down,
  x), axes ``t,-y,x`` (``CDT_AXES``); 16 ps bins (``CDT_MAT_BIN_WIDTH_S``, the published
  ``cdt_reconstruction.py``), bin 0 at t = 0 (the same code); the scan width is not stored
  and the published code sets it per scene (0.6-0.7 m): it must be given.
  Checked on the published letters: they read "UT", U on the left.
* LCT (O'Toole, Lindell & Wetzstein 2018): ``rect_data`` of size (N, N, T) and ``width`` =
  half the scan width (m), as released with the paper; ``bin_resolution`` (s) where a file
  has it, else the published code's 4 ps (``LCT_MAT_BIN_WIDTH_S``). Orientation as the
  published code (``cnlos_reconstruction.m``) displays it: it permutes the data to (t, j, i),
  reverses i, and shows the front view with j running down the image. So index j runs down
  (-y) and index i runs right to left (-x): axes ``-x,-y,t`` (``LCT_AXES``); the letters of
  the released captures then read left to right, seen from the wall. The window starts at
  the direct reflection off the wall ("pre-rectified", t = 0 there); its first
  ``LCT_DIRECT_END_S`` (the 600 bins of 4 ps the published code zeroes) are recorded as the
  direct reflection (attribute ``direct_end_s``), which a reconstruction removes
  (:func:`clnlos.io.capture.without_direct`).
* f-k (Lindell, Wetzstein & O'Toole 2019): ``meas`` of size (N, N, T) = (y, x, t) and
  ``tofgrid`` (N, N), the time of flight (ps) from the laser and detector to each scan
  point. The published code (``cnlos_reconstruction.m`` of nlos-fk) shows the front view as
  ``meas``'s first index running down the image and its second to the right (it reverses
  both and labels both axes from +w to -w, which ``imagesc`` draws back the same way), so
  row i is y = -i: axes ``-y,x,t`` (``FK_AXES``; ``tofgrid`` follows ``meas``'s two scan
  axes). The time of flight is removed (each column moved earlier by it, fractionally,
  counts conserved: t = 0 where the light reaches the wall, as the published code); 32 ps
  bins (the published code's ``bin_resolution``), a 2 m scan (``FK_SCAN_WIDTH_M``: the
  published ``demo.m``'s ``wall_size``, the 2 m x 2 m of every planar scene of the release;
  a scan that is not square must be given its width).
  A ``meas`` of size (N, N, T) without ``tofgrid`` is read the same way, taken as already
  aligned (t = 0 at bin 0).
* Any other file holding one 3-D numeric array, under any name (``tof_data``, ...): read with
  the layout given, else the one :func:`clnlos.io.layout.assumed_layout` assumes, named in
  a note; no bin width, scan width or start is taken (bin 0 at t = 0; the other two must be
  given).
"""

from __future__ import annotations

import struct

import h5py
import numpy as np
import scipy.io

from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.formats.common import (
    align_columns,
    array_capture,
    recorded_layout,
    validate_transient,
)
from clnlos.io.layout import Layout, assumed_layout, parse_axes
from clnlos.runtime.limits import declared_capture

CDT_MAT_BIN_WIDTH_S = 16e-12  # the CDT capture format's histogram bin
FK_MAT_BIN_WIDTH_S = 32e-12   # bin_resolution of the f-k data files
FK_SCAN_WIDTH_M = 2.0         # wall_size of the f-k release's demo.m (2 m x 2 m scans)
LCT_MAT_BIN_WIDTH_S = 4e-12   # the LCT release's SPAD bin (cnlos_reconstruction.m)
LCT_DIRECT_END_S = 600 * LCT_MAT_BIN_WIDTH_S  # the direct reflection the published code zeroes
LCT_RELEASE_BIN_WIDTH_S = 16e-12  # ... and its time bin (4 ps summed in fours, K = 2)
LCT_RELEASE_REFLECTANCE = "retroreflective"  # its published default: (t/T)^2
DIRECT_PEAK_FRACTION = 0.02   # a direct reflection peaks within this fraction of the window
DIRECT_PEAK_OVER_MEDIAN = 10.0  # ... this many times above the window's median
# each layout's stored axes in MATLAB order, as its published code displays them
LCT_AXES = "-x,-y,t"
FK_AXES = "-y,x,t"
CDT_AXES = "t,-y,x"
# MATLAB v7.3 keeps its references and class data in these top-level groups (no variables)
MAT73_INTERNAL = ("#refs#", "#subsystem#")


def _scalar(v, name, path) -> float:
    try:
        x = float(np.asarray(v, np.float64).reshape(()))
    except (TypeError, ValueError):
        raise InputFileError(f"{path}: variable {name!r} must be a number") from None
    if not np.isfinite(x) or x <= 0:
        raise InputFileError(f"{path}: variable {name!r} = {x} must be > 0 and finite")
    return x


def _layout(given: Layout | None, default: str) -> tuple[Layout, bool]:
    """(the layout to read with, whether the user gave it)."""
    return (given, True) if given is not None else (parse_axes(default), False)


def _time_last(shape, given: Layout | None) -> bool:
    """Whether a ``meas`` of MATLAB ``shape`` is the f-k layout (time last) rather than the
    CDT one (time first): where the given layout puts time, else the longest axis last."""
    if given is not None:
        return given.time_axis == 2
    return shape[2] > max(shape[0], shape[1])


def from_lct(rect_data, width, bin_resolution, path, axes: Layout | None = None) -> Capture:
    """The LCT layout (module docstring): ``bin_resolution`` None takes the published 4 ps,
    recorded in the attributes (``bin_width_source``) for the reconstruction's note."""
    if np.ndim(rect_data) != 3:
        raise InputFileError(f"{path}: 'rect_data' must be 3D (N, N, T), got "
                             f"{np.shape(rect_data)}")
    lay, given = _layout(axes, LCT_AXES)
    arr = validate_transient(lay.to_tyx(rect_data), path)
    attrs = {"format": "lct-mat", "reflectance_default": LCT_RELEASE_REFLECTANCE,
             "reflectance_source": "the published code's default for this release (isdiffuse"
                                   " = 0: retroreflective targets, 1/r^2)",
             "bin_width_default_s": LCT_RELEASE_BIN_WIDTH_S,
             "bin_width_default_source": "the published code sums the 4 ps bins in fours",
             "start_source": "the release is rectified: bin 0 is the light's arrival at the "
                             "wall (cnlos_reconstruction.m)",
             **recorded_layout(lay, given, "'rect_data' (MATLAB's order)", np.shape(rect_data),
                               "the LCT release's, as its published code "
                               "(cnlos_reconstruction.m) displays it")}
    if starts_with_direct_reflection(arr):
        attrs["direct_end_s"] = LCT_DIRECT_END_S
    if bin_resolution is None:
        bin_width = LCT_MAT_BIN_WIDTH_S
        attrs["bin_width_source"] = "the published code's 4 ps (cnlos_reconstruction.m)"
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
    return parse_axes(LCT_AXES).from_tyx(transient)


def from_fk(meas, tofgrid, path, axes: Layout | None = None) -> Capture:
    """The f-k layout (module docstring): rows run down the published front view; the
    ``tofgrid`` is oriented with ``meas``'s two scan axes."""
    meas = np.asarray(meas)
    if meas.ndim != 3:
        raise InputFileError(f"{path}: 'meas' must be 3D (N, N, T), got {meas.shape}")
    lay, given = _layout(axes, FK_AXES)
    arr = validate_transient(lay.to_tyx(meas), path)
    attrs = {"format": "fk-mat",
             "bin_width_source": "the published code's bin_resolution (nlos-fk "
                                 "cnlos_reconstruction.m)",
             "scan_width_source": "the published demo.m's wall_size (the release's 2 m x 2 m "
                                  "scans)",
             **recorded_layout(lay, given, "'meas' (MATLAB's order)", meas.shape, "the f-k "
                               "release's, as "
                               "its published code (cnlos_reconstruction.m) displays it")}
    shifts = None
    if tofgrid is not None:
        try:
            tof = lay.scan_to_yx(np.asarray(tofgrid, np.float64))  # rows as the transient's
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
        attrs["start_source"] = ("each scan point's 'tofgrid' removed: t = 0 where the light "
                                 "reaches the wall, as the published code")
    else:
        attrs["start_source"] = ("no 'tofgrid': taken as already aligned, t = 0 at bin 0, as "
                                 "the published code takes such a file")
    ny, nx = arr.shape[1:]
    width = FK_SCAN_WIDTH_M if ny == nx else None
    if width is None:  # the release's scans are square: its 2 m says nothing of this one
        del attrs["scan_width_source"]
        attrs["scan_width_unknown"] = (f"{path} does not store the scan width (the f-k "
                                       f"release's 2 m is of square scans, this one is "
                                       f"{ny} x {nx})")
    return Capture(arr, FK_MAT_BIN_WIDTH_S, 0.0, width, str(path), attrs,
                   time_shift_bins=shifts)


def from_cdt(meas, path, axes: Layout | None = None) -> Capture:
    """The CDT layout (module docstring): (t, y running down, x) -> [t, y, x] with +y up."""
    lay, given = _layout(axes, CDT_AXES)
    arr = validate_transient(lay.to_tyx(meas), path)
    attrs = {"format": "cdt-mat",
             "bin_width_source": "the published code's 16 ps (cdt_reconstruction.py)",
             "start_source": "bin 0 at t = 0, as the published code (cdt_reconstruction.py)",
             "scan_width_unknown": f"{path} does not store the scan width (the published "
                                   "code sets it per scene, 0.6-0.7 m)",
             **recorded_layout(lay, given, "'meas' (MATLAB's order)", np.shape(meas), "the CDT "
                               "release's, "
                               "as its published code (cdt_reconstruction.py) displays it")}
    return Capture(arr, CDT_MAT_BIN_WIDTH_S, 0.0, None, str(path), attrs)


def _matlab_order(ds) -> tuple[int, ...]:
    """A v7.3 dataset's MATLAB size (h5py gives it reversed)."""
    return tuple(int(s) for s in (ds.shape or ())[::-1])


def mat73_arrays(f) -> dict[str, h5py.Dataset]:
    """The top-level numeric 3-D variables of a MATLAB v7.3 file, by name."""
    return {k: v for k, v in f.items() if k not in MAT73_INTERNAL
            and isinstance(v, h5py.Dataset) and len(v.shape or ()) == 3
            and v.dtype.kind in "biuf"}


def _declared_mat73(f, path, axes: Layout | None) -> None:
    """Declare the capture variable's size before it is read, as [t, y, x] in the layout
    :func:`read_mat73` will read it with."""
    if isinstance(f.get("rect_data"), h5py.Dataset) and len(f["rect_data"].shape or ()) == 3:
        m = _matlab_order(f["rect_data"])
        lay, _ = _layout(axes, LCT_AXES)
        declared_capture(path, lay.shape_tyx(m), f["rect_data"].dtype.itemsize,
                         bin_width_s=LCT_MAT_BIN_WIDTH_S if "bin_resolution" not in f
                         else None)
    elif isinstance(f.get("meas"), h5py.Dataset) and len(f["meas"].shape or ()) == 3:
        m = _matlab_order(f["meas"])
        fk = "tofgrid" in f or _time_last(m, axes)
        lay, _ = _layout(axes, FK_AXES if fk else CDT_AXES)
        declared_capture(path, lay.shape_tyx(m), f["meas"].dtype.itemsize,
                         bin_width_s=FK_MAT_BIN_WIDTH_S if fk else CDT_MAT_BIN_WIDTH_S)


def read_mat73(f, path, axes: Layout | None = None) -> Capture:
    """MATLAB v7.3 (h5py's axis order is MATLAB's reversed): the LCT, f-k and CDT layouts by
    their variables, else the file's one 3-D array (:func:`one_array`)."""
    if "rect_data" not in f and "meas" not in f:
        name, ds = one_array(mat73_arrays(f), path, "variable")
        return array_capture(ds, path, given=axes, what=f"variable {name!r} (MATLAB's order)",
                             fmt="mat-array", order=_matlab_order(ds), matlab73=True)
    _declared_mat73(f, path, axes)
    try:
        if "rect_data" in f:
            bin_res = f["bin_resolution"][()] if "bin_resolution" in f else None
            return from_lct(np.transpose(f["rect_data"][()]), f["width"][()], bin_res, path,
                            axes)
        meas = np.transpose(f["meas"][()])  # back to MATLAB's order
    except KeyError as exc:
        raise InputFileError(f"{path}: missing variable {exc}") from None
    if meas.ndim != 3:
        raise InputFileError(f"{path}: 'meas' must be 3D, got shape {meas.shape}")
    if "tofgrid" in f or _time_last(meas.shape, axes):
        tof = np.transpose(f["tofgrid"][()]) if "tofgrid" in f else None
        return from_fk(meas, tof, path, axes)
    return from_cdt(meas, path, axes)


def one_array(arrays: dict, path, kind: str):
    """(name, array) of the one 3-D numeric array a file of another layout holds; an
    InputFileError naming what it holds instead (none, or several to choose from)."""
    if len(arrays) == 1:
        return next(iter(arrays.items()))
    if not arrays:
        raise InputFileError(f"{path}: no 3-D numeric {kind} (a transient) found; the known "
                             "layouts have 'meas' (CDT, f-k) or 'rect_data' (LCT)")
    shapes = ", ".join(f"{k} {tuple(getattr(v, 'shape', ()))}" for k, v in arrays.items())
    raise InputFileError(f"{path}: {len(arrays)} 3-D {kind}s ({shapes}): clnlos reads a file "
                         "with one; save the transient alone")


# bytes per value of MATLAB's numeric classes (whosmat); anything else counted as double
MAT_CLASS_BYTES = {"double": 8, "single": 4, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
                   "int32": 4, "uint32": 4, "int64": 8, "uint64": 8, "logical": 1}


def _declared_mat5(path, axes: Layout | None) -> None:
    """Declare the capture variable's size from the file's variable headers
    (scipy.io.whosmat) before loadmat reads everything, as [t, y, x] in the layout the
    reader will take. A file whose headers cannot be listed is left to :func:`read_mat5`'s
    own error."""
    try:
        info = {name: (shape, cls) for name, shape, cls in scipy.io.whosmat(path)}
    except Exception:  # any failure is reported by loadmat below
        return
    name = "rect_data" if "rect_data" in info else "meas" if "meas" in info else None
    if name is None:
        three = {k: v for k, v in info.items() if len(v[0]) == 3}
        if len(three) != 1:
            return
        name = next(iter(three))
    shape, cls = info[name]
    if len(shape) != 3:
        return
    bin_width = None
    if name == "rect_data":
        lay, _ = _layout(axes, LCT_AXES)
        bin_width = None if "bin_resolution" in info else LCT_MAT_BIN_WIDTH_S
    elif name == "meas":
        fk = "tofgrid" in info or _time_last(shape, axes)
        lay, _ = _layout(axes, FK_AXES if fk else CDT_AXES)
        bin_width = FK_MAT_BIN_WIDTH_S if fk else CDT_MAT_BIN_WIDTH_S
    else:
        lay = axes or assumed_layout(shape)
    declared_capture(path, lay.shape_tyx(shape), MAT_CLASS_BYTES.get(cls, 8),
                     bin_width_s=bin_width)


def read_mat5(path, axes: Layout | None = None) -> Capture:
    _declared_mat5(path, axes)
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
        return from_lct(d["rect_data"], d["width"], d.get("bin_resolution"), path, axes)
    if "meas" in d:
        meas = np.asarray(d["meas"])
        if meas.ndim != 3:
            raise InputFileError(f"{path}: 'meas' must be 3D, got shape {meas.shape}")
        if "tofgrid" in d or _time_last(meas.shape, axes):
            return from_fk(meas, d.get("tofgrid"), path, axes)
        return from_cdt(meas, path, axes)
    arrays = {k: v for k, v in d.items() if not k.startswith("__")
              and isinstance(v, np.ndarray) and v.ndim == 3 and v.dtype.kind in "biuf"}
    name, arr = one_array(arrays, path, "variable")
    return array_capture(arr, path, given=axes, what=f"variable {name!r} (MATLAB's order)",
                         fmt="mat-array", order=arr.shape)

"""y-tal HDF5 captures (the Zaragoza NLOS format of ``tal.io.write_capture``), read and written.

Layout, as y-tal's ``write_hdf5`` lays it out (one dataset per field of NLOSCaptureData):

* ``H`` float (T, Sx, Sy) for ``H_format`` = T_Sx_Sy (an h5py enum dataset of shape (1,),
  values of ``tal.enums.HFormat``: T_Sx_Sy = 1, T_Lx_Ly_Sx_Sy = 2, T_Si = 3, T_Li_Si = 4);
* ``sensor_grid_xyz`` / ``laser_grid_xyz`` (Sx, Sy, 3) in metres for ``*_grid_format`` =
  X_Y_3 (= 2; N_3 = 1), ``*_grid_normals`` likewise, ``sensor_xyz`` / ``laser_xyz`` (3,)
  the device origins; the relay wall is the plane z = 0, hidden objects at z > 0;
* ``delta_t`` and ``t_start``: bin width and start of bin 0 in metres of optical path;
* ``t_accounts_first_and_last_bounces``: whether H's time includes the flights from the
  laser to the wall and from the wall to the sensor;
* ``scene_info``: a YAML string; a field that is None is ``h5py.Empty``.

clnlos reads confocal captures on a planar regular grid: laser and sensor grids equal, a grid
of constant pitch along two perpendicular axes in the z = 0 plane. Which grid index runs
along x and which along y, and in which direction, comes from the coordinates; the result
is [t, y, x] with x and y increasing with index; the grid's centre is kept
(``Capture.scan_center_m``: the volume is placed there). With
``t_accounts_first_and_last_bounces`` the per-point flight |laser - p| + |p - sensor| is
removed (each column moved earlier, fractionally, counts conserved; the window cut to the
bins every scan point recorded; the shifts kept in ``Capture.time_shift_bins``). Anything else
(non-confocal, irregular grids, another plane) is a one-line error.
"""

from __future__ import annotations

import json

import h5py
import numpy as np

from clnlos.physics.constants import C0
from clnlos.errors import InputFileError
from clnlos.io.capture import Capture
from clnlos.io.formats.common import align_columns, declared_dataset, validate_transient

H_FORMAT = {"UNKNOWN": 0, "T_Sx_Sy": 1, "T_Lx_Ly_Sx_Sy": 2, "T_Si": 3, "T_Li_Si": 4}
GRID_FORMAT = {"UNKNOWN": 0, "N_3": 1, "X_Y_3": 2}
VOLUME_FORMAT = {"UNKNOWN": 0, "N_3": 1, "X_Y_Z_3": 2, "X_Y_3": 3}
GRID_TOL = 1e-4  # relative tolerance of the regular-grid check (of the pitch)


def _value(f, key):
    """A dataset's value as y-tal reads it (Empty -> None, size-1 arrays -> scalars)."""
    if key not in f:
        return None
    ds = f[key]
    if ds.shape is None:  # h5py.Empty
        return None
    v = ds[()]
    if isinstance(v, np.ndarray) and v.size == 1:
        v = np.squeeze(v)[()]
    if isinstance(v, bytes):
        v = v.decode("utf-8", "replace")
    return v


def _seconds(metres) -> float | None:
    """A y-tal time in metres of path as seconds; None unless a finite number."""
    try:
        t = float(metres) / C0
    except (TypeError, ValueError):
        return None
    return t if np.isfinite(t) else None


def _grid_axes(grid: np.ndarray, path) -> tuple[np.ndarray, np.ndarray, float]:
    """(unit vector along index 0, along index 1, pitch) of a regular planar grid (Sx, Sy, 3)."""
    n0, n1 = grid.shape[:2]
    if n0 < 2 or n1 < 2:
        raise InputFileError(f"{path}: the scan grid must be at least 2 x 2, got {n0} x {n1}")
    a = (grid[-1, 0] - grid[0, 0]) / (n0 - 1)
    b = (grid[0, -1] - grid[0, 0]) / (n1 - 1)
    pitch = float(np.linalg.norm(a))
    i, j = np.meshgrid(np.arange(n0), np.arange(n1), indexing="ij")
    model = grid[0, 0] + i[..., None] * a + j[..., None] * b
    if np.abs(grid[..., 2] - grid[0, 0, 2]).max() > GRID_TOL * max(pitch, 1e-12):
        raise InputFileError(f"{path}: the scan grid is not in a plane z = const (the y-tal "
                             "relay wall is the plane z = 0)")
    if (pitch == 0 or abs(np.linalg.norm(b) - pitch) > GRID_TOL * pitch
            or np.abs(model - grid).max() > GRID_TOL * pitch
            or abs(float(np.dot(a, b))) > GRID_TOL * pitch * pitch):
        raise InputFileError(f"{path}: the scan grid is not a regular square grid (constant "
                             "pitch along two perpendicular axes): clnlos reconstructs "
                             "confocal captures on such grids only")
    return a / pitch, b / pitch, pitch


def read_tal(f, path) -> Capture:
    h_format = _value(f, "H_format")
    if h_format != H_FORMAT["T_Sx_Sy"]:
        name = {v: k for k, v in H_FORMAT.items()}.get(h_format, h_format)
        raise InputFileError(f"{path}: y-tal H_format {name} is not confocal (T, Sx, Sy): "
                             "clnlos reconstructs confocal captures only")
    for key in ("sensor_grid_format", "laser_grid_format"):
        if _value(f, key) != GRID_FORMAT["X_Y_3"]:
            raise InputFileError(f"{path}: {key} must be X_Y_3 (a grid of scan points); an "
                                 "irregular list of points is not supported")
    sensor = np.asarray(_value(f, "sensor_grid_xyz"), np.float64)
    laser = np.asarray(_value(f, "laser_grid_xyz"), np.float64)
    declared_dataset(f["H"], path, bin_width_s=_seconds(_value(f, "delta_t")),
                     start_s=_seconds(_value(f, "t_start")) or 0.0)  # before reading it
    H = np.asarray(f["H"][()])
    if H.ndim != 3 or sensor.shape != H.shape[1:] + (3,):
        raise InputFileError(f"{path}: H {H.shape} and sensor_grid_xyz {sensor.shape} do not "
                             "match (T, Sx, Sy) and (Sx, Sy, 3)")
    if laser.shape != sensor.shape or not np.allclose(laser, sensor, rtol=0, atol=1e-6):
        raise InputFileError(f"{path}: laser and sensor grids differ: not a confocal capture "
                             "(clnlos reconstructs confocal captures only)")
    delta_t = _value(f, "delta_t")
    if delta_t is None or not np.isfinite(delta_t) or delta_t <= 0:
        raise InputFileError(f"{path}: delta_t = {delta_t!r} must be > 0 (metres of path)")
    t_start = _value(f, "t_start")
    t_start = 0.0 if t_start is None else float(t_start)
    ax0, ax1, pitch = _grid_axes(sensor, path)
    # which index runs along x, and the directions
    if abs(ax0[0]) >= abs(ax0[1]):
        x_axis, y_axis, x_dir, y_dir = 1, 2, ax0, ax1
    else:
        x_axis, y_axis, x_dir, y_dir = 2, 1, ax1, ax0
    if abs(abs(x_dir[0]) - 1) > 1e-3 or abs(abs(y_dir[1]) - 1) > 1e-3:
        raise InputFileError(f"{path}: the scan grid's axes are not along x and y of the "
                             "z = 0 plane")
    arr = np.transpose(H, (0, y_axis, x_axis))  # [t, y-index, x-index]
    pos = np.transpose(sensor, (y_axis - 1, x_axis - 1, 2))
    if x_dir[0] < 0:
        arr, pos = arr[:, :, ::-1], pos[:, ::-1]
    if y_dir[1] < 0:
        arr, pos = arr[:, ::-1, :], pos[::-1]
    arr = validate_transient(arr, path)
    bounces = bool(_value(f, "t_accounts_first_and_last_bounces"))
    shifts = None
    attrs = {"format": "y-tal", "tal_t_accounts_first_and_last_bounces": bounces}
    if bounces:
        lx = _value(f, "laser_xyz")
        sx = _value(f, "sensor_xyz")
        if lx is None or sx is None:
            raise InputFileError(f"{path}: t_accounts_first_and_last_bounces without "
                                 "laser_xyz / sensor_xyz")
        flight = (np.linalg.norm(pos - np.asarray(lx, np.float64), axis=-1)
                  + np.linalg.norm(pos - np.asarray(sx, np.float64), axis=-1))
        attrs["aligned_from_bins"] = arr.shape[0]
        arr, shifts = align_columns(arr, flight / delta_t, path,
                                    "t_accounts_first_and_last_bounces (the flight from "
                                    "laser_xyz and to sensor_xyz)")
    info = _value(f, "scene_info")
    if isinstance(info, str):
        attrs["tal_scene_info"] = info
        try:  # a capture clnlos wrote records its setup under "clnlos" (JSON is YAML)
            recorded = json.loads(info).get("clnlos", {})
        except (json.JSONDecodeError, AttributeError):
            recorded = {}
        if isinstance(recorded, dict):
            attrs.update({k: v for k, v in recorded.items() if k in ("scene", "slab")})
    ny, nx = arr.shape[1:]
    center = (float(pos[..., 0].mean()), float(pos[..., 1].mean()))
    return Capture(arr, float(delta_t) / C0, t_start / C0, pitch * nx, str(path), attrs,
                   time_shift_bins=shifts, scan_center_m=center, scan_height_m=pitch * ny)


def write_tal(path, transient: np.ndarray, *, bin_width_s: float, start_s: float,
              scan_width_m: float, scene_info: dict | None = None,
              scan_center_m=(0.0, 0.0)) -> None:
    """Write a confocal capture [t, y, x] as y-tal's ``write_capture`` lays it out (H as
    (T, Sx, Sy) with Sx along +x and Sy along +y, the relay wall at z = 0 with normals +z
    towards the hidden scene, times in metres of path, no first/last bounce; the grid centred
    at ``scan_center_m``) to ``path``
    (callers make it atomic: :func:`clnlos.io.outputs.write_group`)."""
    nt, ny, nx = transient.shape
    pitch = scan_width_m / nx
    xs = (np.arange(nx) + 0.5) * pitch - scan_width_m / 2 + scan_center_m[0]
    ys = (np.arange(ny) + 0.5) * pitch - pitch * ny / 2 + scan_center_m[1]
    X, Y = np.meshgrid(xs, ys, indexing="ij")  # (Sx, Sy)
    # float64 coordinates and times: y-tal reads any float; float32 would move the bin width
    # by 1e-8 and the scan width by 1e-7, which a deep deconvolution amplifies
    grid = np.stack([X, Y, np.zeros_like(X)], axis=-1)
    normals = np.zeros_like(grid)
    normals[..., 2] = 1.0
    h_enum = h5py.enum_dtype(H_FORMAT, basetype="i")
    g_enum = h5py.enum_dtype(GRID_FORMAT, basetype="i")
    fields = {
        "H": np.ascontiguousarray(np.transpose(transient, (0, 2, 1)), np.float32),
        "sensor_xyz": np.zeros(3), "sensor_grid_xyz": grid,
        "sensor_grid_normals": normals,
        "laser_xyz": np.zeros(3), "laser_grid_xyz": grid,
        "laser_grid_normals": normals,
        "delta_t": np.float64(bin_width_s * C0), "t_start": np.float64(start_s * C0),
        "t_accounts_first_and_last_bounces": np.bool_(False),
    }
    with h5py.File(path, "w") as f:
        for k, v in fields.items():
            f[k] = v
        for key, dt, val in (("H_format", h_enum, H_FORMAT["T_Sx_Sy"]),
                             ("sensor_grid_format", g_enum, GRID_FORMAT["X_Y_3"]),
                             ("laser_grid_format", g_enum, GRID_FORMAT["X_Y_3"])):
            ds = f.create_dataset(key, (1,), dtype=dt)
            ds[0] = val
        f["volume_format"] = h5py.Empty(float)
        # y-tal stores dicts as YAML; JSON is YAML
        f["scene_info"] = json.dumps(scene_info or {"original_format": "clnlos"})

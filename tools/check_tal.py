#!/usr/bin/env python3
"""Cross-check clnlos's y-tal files with y-tal itself (run with a Python that has y-tal
installed, e.g. ``python3 -m venv /tmp/ytal && /tmp/ytal/bin/pip install y-tal``; y-tal is not
a clnlos dependency: it pulls pyvista, numba and pinned Pillow/imageio).

    PY_WITH_YTAL tools/check_tal.py read CAPTURE.hdf5    # y-tal reads a clnlos-written file
    PY_WITH_YTAL tools/check_tal.py write OUT.hdf5       # y-tal writes a confocal capture
    clnlos reconstruct OUT.hdf5 -o v.h5 --method lct     # ... that clnlos reads

``write`` makes an 8 x 6 confocal grid (x along Sx, y along Sy, relay wall z = 0) with one
bright point at (Sx = 0, Sy = 5) in time bin 40 and prints what it wrote.
"""

import sys

import numpy as np


def read(path: str) -> None:
    import tal

    d = tal.io.read_capture(path)
    print({"H_shape": d.H.shape, "H_format": d.H_format.name, "confocal": d.is_confocal(),
           "delta_t_m": float(d.delta_t), "t_start_m": float(d.t_start),
           "grid_format": d.sensor_grid_format.name, "grid_shape": d.sensor_grid_xyz.shape,
           "bounces": bool(d.t_accounts_first_and_last_bounces),
           "scene_info_keys": sorted((d.scene_info or {}).keys())})


def write(path: str) -> None:
    import tal
    from tal.enums import GridFormat, HFormat

    nt, nx, ny, pitch = 96, 8, 6, 0.05
    xs = (np.arange(nx) + 0.5) * pitch - nx * pitch / 2
    ys = (np.arange(ny) + 0.5) * pitch - ny * pitch / 2
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    grid = np.stack([X, Y, np.zeros_like(X)], -1).astype(np.float32)
    normals = np.zeros_like(grid)
    normals[..., 2] = 1
    H = np.ones((nt, nx, ny), np.float32)
    H[40, 0, 5] = 500.0
    d = tal.io.NLOSCaptureData()
    d.H, d.H_format = H, HFormat.T_Sx_Sy
    d.sensor_xyz = d.laser_xyz = np.zeros(3, np.float32)
    d.sensor_grid_xyz = d.laser_grid_xyz = grid
    d.sensor_grid_normals = d.laser_grid_normals = normals
    d.sensor_grid_format = d.laser_grid_format = GridFormat.X_Y_3
    d.delta_t, d.t_start = np.float32(16e-12 * 299792458.0), np.float32(0.0)
    d.t_accounts_first_and_last_bounces = False
    d.scene_info = {"original_format": "HDF5_TAL"}
    tal.io.write_capture(path, d)
    print(f"wrote {path}: H (T, Sx, Sy) = {H.shape}, bright point at Sx = 0 (x = {xs[0]:.3f} "
          f"m), Sy = 5 (y = {ys[5]:.3f} m), bin 40")


if __name__ == "__main__":
    {"read": read, "write": write}[sys.argv[1]](sys.argv[2])

"""Capture formats: every reader gives the same capture (and the same reconstruction) for the
same data, files are recognised by content, bad layouts are one-line errors. Each format is
built with its own tools where they install (scipy.io.savemat for MATLAB v5; h5py laid out
as MATLAB 7.3 and as y-tal's write_hdf5 writes -- y-tal itself needs pyvista, numba and pinned
Pillow/imageio, so the test writes its layout field by field, and tools/check_tal.py reads a
clnlos-written file with y-tal where it is installed)."""

import json

import h5py
import numpy as np
import pytest
import scipy.io

from clnlos.io.formats.mat import lct_rect_data
from clnlos import C0
from clnlos.app.cli import main
from clnlos.config import ReconstructionConfig
from clnlos.errors import InputFileError
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.files import write_capture
from clnlos.io.formats import read_capture, sniff
from clnlos.io.formats.common import shift_earlier
from clnlos.io.formats.tal import GRID_FORMAT, H_FORMAT, write_tal

NT, NY, NX = 96, 6, 8  # a rectangular scan on purpose: x and y cannot be swapped unnoticed


@pytest.fixture(scope="module")
def data():
    """A transient [t, y, x] with a marked corner (y high, x low) and a time peak."""
    rng = np.random.default_rng(0)
    tau = rng.poisson(2.0, (NT, NY, NX)).astype(np.float32)
    tau[40:44, NY - 1, 0] += 500.0
    tau[60, 1, NX - 2] += 300.0
    return tau


def _same(cap, tau, bw=16e-12, width=0.4):
    assert cap.transient.shape == tau.shape
    np.testing.assert_array_equal(cap.transient, tau)
    assert cap.bin_width_s == pytest.approx(bw, rel=1e-6)
    if width is not None:
        assert cap.scan_width_m == pytest.approx(width, rel=1e-6)


def test_clnlos_and_npy(tmp_path, data):
    write_capture(tmp_path / "c.h5", data, bin_width_s=16e-12, start_s=0.0, scan_width_m=0.4)
    _same(read_capture(tmp_path / "c.h5"), data)
    np.save(tmp_path / "c.npy", data)
    cap = read_capture(tmp_path / "c.npy")
    np.testing.assert_array_equal(cap.transient, data)
    assert cap.bin_width_s is None and cap.scan_width_m is None
    # content, not extension: an .npy renamed .h5 is still read as an array
    (tmp_path / "c.npy").rename(tmp_path / "renamed.h5")
    assert sniff(tmp_path / "renamed.h5") == "npy"


def _tal_layout(path, H, grid, *, h_format=1, laser_grid=None, bounces=False, delta_t=None,
                t_start=0.0, origin=(0.0, 0.0, 0.0)):
    """A file laid out field by field as y-tal's write_hdf5 writes NLOSCaptureData."""
    h_enum = h5py.enum_dtype(H_FORMAT, basetype="i")
    g_enum = h5py.enum_dtype(GRID_FORMAT, basetype="i")
    with h5py.File(path, "w") as f:
        f["H"] = H
        ds = f.create_dataset("H_format", (1,), dtype=h_enum)
        ds[0] = h_format
        for who, g in (("sensor", grid), ("laser", grid if laser_grid is None else laser_grid)):
            f[f"{who}_xyz"] = np.asarray(origin, np.float32)
            f[f"{who}_grid_xyz"] = g.astype(np.float32)
            n = np.zeros_like(g)
            n[..., 2] = 1
            f[f"{who}_grid_normals"] = n.astype(np.float32)
            ds = f.create_dataset(f"{who}_grid_format", (1,), dtype=g_enum)
            ds[0] = 2
        f["volume_format"] = h5py.Empty(float)
        f["delta_t"] = np.float32(delta_t if delta_t is not None else 16e-12 * C0)
        f["t_start"] = np.float32(t_start)
        f["t_accounts_first_and_last_bounces"] = np.bool_(bounces)
        f["scene_info"] = "original_format: HDF5_TAL\n"


def _grid(nx, ny, pitch, flip_x=False, flip_y=False):
    xs = (np.arange(nx) + 0.5) * pitch - nx * pitch / 2
    ys = (np.arange(ny) + 0.5) * pitch - ny * pitch / 2
    xs, ys = (xs[::-1] if flip_x else xs), (ys[::-1] if flip_y else ys)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([X, Y, np.zeros_like(X)], -1)


@pytest.mark.parametrize("flip_x,flip_y,swap", [(False, False, False), (True, False, False),
                                                (False, True, True), (True, True, True)])
def test_tal_orientation_from_grid(tmp_path, data, flip_x, flip_y, swap):
    """Whatever grid index runs along x or y and in which direction, the capture comes out
    [t, y, x] with x and y increasing with index."""
    pitch = 0.05
    grid = _grid(NX, NY, pitch, flip_x, flip_y)  # (Sx, Sy, 3)
    H = np.transpose(data, (0, 2, 1))  # (T, Sx, Sy)
    if flip_x:
        H = H[:, ::-1, :]
    if flip_y:
        H = H[:, :, ::-1]
    if swap:  # first index along y
        grid, H = np.transpose(grid, (1, 0, 2)), np.transpose(H, (0, 2, 1))
    _tal_layout(tmp_path / "t.hdf5", H, grid)
    cap = read_capture(tmp_path / "t.hdf5")
    _same(cap, data, width=NX * pitch)
    assert cap.attrs["format"] == "y-tal"


def test_tal_round_trip_and_bounces(tmp_path, data):
    write_tal(tmp_path / "w.hdf5", data, bin_width_s=16e-12, start_s=1e-10, scan_width_m=0.4)
    cap = read_capture(tmp_path / "w.hdf5")
    _same(cap, data)
    assert cap.start_s == pytest.approx(1e-10, rel=1e-5)
    # first and last bounces: a laser/sensor origin 1 m in front of the wall adds 2 |o - p|
    # to every time; the reader removes it (fractional shifts, counts conserved)
    origin = np.array([0.0, 0.0, -1.0])
    grid = _grid(NX, NY, 0.05)
    flight = 2 * np.linalg.norm(grid - origin, axis=-1)  # (Sx, Sy) metres
    dt_m = 16e-12 * C0
    delayed = np.zeros((NT + 600, NX, NY), np.float32)
    shift = flight / dt_m
    data = data.copy()
    data[[0, -1]] = 0  # so no count crosses the window's edges in either direction
    H = np.transpose(data, (0, 2, 1))
    k0 = np.floor(shift).astype(int)
    f = shift - k0
    for i in range(NX):
        for j in range(NY):
            delayed[k0[i, j]:k0[i, j] + NT, i, j] += (1 - f[i, j]) * H[:, i, j]
            delayed[k0[i, j] + 1:k0[i, j] + 1 + NT, i, j] += f[i, j] * H[:, i, j]
    _tal_layout(tmp_path / "b.hdf5", delayed, grid, bounces=True, origin=origin)
    read = read_capture(tmp_path / "b.hdf5")
    back = read.transient[:NT]
    # a fractional shift there and back blurs by up to one bin, but moves no mass and no
    # centroid: per column, equal sums and time centroids within 0.02 bins
    t = np.arange(NT)[:, None, None]
    assert np.allclose(back.sum(0), data.sum(0), rtol=1e-4)
    assert np.abs((back * t).sum(0) / back.sum(0) - (data * t).sum(0) / data.sum(0)).max() < 0.02
    # the shifts are kept (the reconstruction bounds its slab SNR by them) and the window
    # ends where the most delayed column's data end: no zeros stand in for unrecorded bins
    np.testing.assert_allclose(read.time_shift_bins, shift.T, rtol=1e-6)  # float32 delta_t
    assert read.transient.shape[0] == int(np.floor(NT + 600 - shift.max()))
    assert read.attrs["aligned_from_bins"] == NT + 600
    _tal_layout(tmp_path / "c.hdf5", delayed[:500], grid, bounces=True, origin=origin)
    assert read_capture(tmp_path / "c.hdf5").transient.shape[0] == int(500 - shift.max())
    _tal_layout(tmp_path / "d.hdf5", delayed[:NT], grid, bounces=True, origin=origin)
    with pytest.raises(InputFileError, match="t_accounts_first_and_last_bounces.*426.5 bins"):
        read_capture(tmp_path / "d.hdf5")  # the flight is longer than the window


@pytest.mark.parametrize("what,needle", [("non-confocal", "confocal"), ("exhaustive", "confocal"),
                                         ("irregular", "regular"), ("tilted", "z = const")])
def test_tal_unsupported_layouts_are_errors(tmp_path, data, what, needle):
    grid = _grid(NX, NY, 0.05)
    H = np.transpose(data, (0, 2, 1))
    kw = {}
    if what == "non-confocal":
        kw["laser_grid"] = np.repeat(np.repeat(grid[:1, :1], NX, 0), NY, 1)
    elif what == "exhaustive":
        kw["h_format"] = 2
    elif what == "irregular":
        grid = grid.copy()
        grid[2, 3, 0] += 0.01
    else:
        grid = grid.copy()
        grid[..., 2] = 0.1 * grid[..., 0]
    _tal_layout(tmp_path / "x.hdf5", H, grid, **kw)
    with pytest.raises(InputFileError, match=needle):
        read_capture(tmp_path / "x.hdf5")


def test_matlab_layouts(tmp_path, data):
    """O'Toole's LCT layout (rect_data in the published orientation, width, bin_resolution) and Lindell's f-k
    layout (meas (y, x, t) + tofgrid in ps) in MATLAB v5 via scipy.io.savemat, the CDT layout
    (meas (t, y down, x)) in v5 and in v7.3 (HDF5, axes reversed as MATLAB writes them)."""
    rect = lct_rect_data(data)
    scipy.io.savemat(tmp_path / "lct.mat", {"rect_data": rect, "width": 0.2,
                                             "bin_resolution": 16e-12})
    assert sniff(tmp_path / "lct.mat") == "mat5"
    _same(read_capture(tmp_path / "lct.mat"), data, width=0.4)
    tof = np.full((NY, NX), 64.0)  # 64 ps = 2 bins of 32 ps
    padded = np.concatenate([np.zeros((2, NY, NX), np.float32), data])
    scipy.io.savemat(tmp_path / "fk.mat", {"meas": np.transpose(padded, (1, 2, 0))[::-1],
                                            "tofgrid": tof})  # rows running down
    cap = read_capture(tmp_path / "fk.mat")
    assert cap.bin_width_s == 32e-12 and cap.scan_width_m is None
    np.testing.assert_allclose(cap.transient[:NT], data, atol=1e-4)
    cdt = data[:, ::-1, :]  # y running down
    scipy.io.savemat(tmp_path / "cdt5.mat", {"meas": cdt})
    _same(read_capture(tmp_path / "cdt5.mat"), data, width=None)
    with h5py.File(tmp_path / "cdt73.mat", "w") as f:
        f["meas"] = np.transpose(cdt)  # h5py order = MATLAB's reversed
    _same(read_capture(tmp_path / "cdt73.mat"), data, width=None)


def test_same_data_same_volume_across_formats(tmp_path, queue):
    """A point target: clnlos HDF5, y-tal HDF5 and the LCT v5 .mat reconstruct to the same
    volume (correlation >= 0.98, identical here) and the same peak depth."""
    from reference.scene_ref import points_transient

    tau = points_transient([(0.04, -0.03, 0.3)], [1], 128, 8, 0.4, 16e-12).astype(np.float32)
    tau = np.round(tau / tau.max() * 1000).astype(np.float32)
    write_capture(tmp_path / "a.h5", tau, bin_width_s=16e-12, start_s=0.0, scan_width_m=0.4)
    write_tal(tmp_path / "b.hdf5", tau, bin_width_s=16e-12, start_s=0.0, scan_width_m=0.4)
    scipy.io.savemat(tmp_path / "c.mat", {"rect_data": lct_rect_data(tau),
                                           "width": 0.2, "bin_resolution": 16e-12})
    cfg = ReconstructionConfig(method="lct").validate()
    vols = [reconstruct(read_capture(tmp_path / n), cfg, device=queue).volume
            for n in ("a.h5", "b.hdf5", "c.mat")]
    for v in vols[1:]:
        assert np.corrcoef(v.ravel(), vols[0].ravel())[0, 1] >= 0.98
        assert np.argmax(v.max(axis=(1, 2))) == np.argmax(vols[0].max(axis=(1, 2)))
        assert np.unravel_index(np.argmax(v.max(0)), v.shape[1:]) == \
            np.unravel_index(np.argmax(vols[0].max(0)), v.shape[1:])


def test_shift_earlier_conserves_counts():
    a = np.zeros((10, 1, 2), np.float32)
    a[5, 0, 0] = 4.0
    a[5, 0, 1] = 4.0
    out = shift_earlier(a, np.array([[2.0, 1.25]]))
    assert out[3, 0, 0] == 4.0
    # 1.25 bins earlier: 3/4 of the count one bin earlier, 1/4 two bins (centroid 5 - 1.25)
    assert out[4, 0, 1] == pytest.approx(3.0) and out[3, 0, 1] == pytest.approx(1.0)
    with pytest.raises(InputFileError):
        shift_earlier(a, np.array([[-1.0, 0.0]]))


def test_cli_reads_every_format_and_npy_needs_geometry(tmp_path, capsys, data):
    np.save(tmp_path / "c.npy", data)
    assert main(["reconstruct", str(tmp_path / "c.npy"), "-o", str(tmp_path / "o.h5")]) == 2
    assert "--bin-width" in capsys.readouterr().err
    assert main(["reconstruct", str(tmp_path / "c.npy"), "-o", str(tmp_path / "o.h5"),
                 "--bin-width", "16e-12", "--scan-width", "0.4"]) == 0
    with h5py.File(tmp_path / "o.h5") as f:
        assert f.attrs["clnlos_version"] and f.attrs["capture"].endswith("c.npy")
        assert f.attrs["device"]
    (tmp_path / "junk.h5").write_bytes(b"\x00" * 600)
    assert main(["reconstruct", str(tmp_path / "junk.h5"), "-o", str(tmp_path / "p.h5")]) == 2
    assert "not a capture file" in capsys.readouterr().err


def test_simulate_format_tal_reconstructs_like_clnlos(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text("""seed = 1
[scan]
width_m = 0.3
points = 8
[time]
bin_width_s = 32e-12
bins = 120
[[objects]]
shape = "rectangle"
size_m = [0.1, 0.06]
translate_m = [0.03, 0.0, 0.4]
[slab]
thickness_m = 0.0254
mu_a = 0.53
mu_s_prime = 262.0
n = 1.12
""")
    for fmt in ("clnlos", "tal"):
        assert main(["simulate", str(scene), "-o", str(tmp_path / f"{fmt}.h5"), "--format",
                     fmt]) == 0
    a, b = read_capture(tmp_path / "clnlos.h5"), read_capture(tmp_path / "tal.h5")
    np.testing.assert_array_equal(a.transient, b.transient)
    assert b.recorded_slab() == a.recorded_slab() and a.recorded_slab() is not None
    for fmt in ("clnlos", "tal"):
        assert main(["reconstruct", str(tmp_path / f"{fmt}.h5"), "-o",
                     str(tmp_path / f"v_{fmt}.h5")]) == 0
    vols = [h5py.File(tmp_path / f"v_{fmt}.h5")["volume"][()] for fmt in ("clnlos", "tal")]
    np.testing.assert_allclose(vols[0], vols[1], rtol=1e-5, atol=1e-6 * vols[0].max())
    with h5py.File(tmp_path / "tal.h5") as f:
        assert json.loads(f["scene_info"][()])["original_format"] == "clnlos"


def test_fk_layout_rows_run_down_and_tofgrid_follows_them(tmp_path):
    """f-k's meas (y, x, t): the published front view shows row 0 at the top, so clnlos's y
    (up) is the reversed row; the tofgrid is moved with its rows (an arrival delayed by each
    row's time of flight lands in one bin after alignment)."""
    n, nt = 6, 64
    meas = np.zeros((n, n, nt), np.float32)
    tof = np.zeros((n, n))
    for i in range(n):
        tof[i] = 32.0 * i  # ps: i bins of 32 ps
        meas[i, :, 10 + i] = 5.0
    meas[0, 0, 10] = 50.0  # the top-left of the published view
    scipy.io.savemat(tmp_path / "fk.mat", {"meas": meas, "tofgrid": tof})
    cap = read_capture(tmp_path / "fk.mat")
    assert np.all(cap.transient[10] > 0) and not cap.transient[11:].any()
    t, y, x = np.unravel_index(np.argmax(cap.transient), cap.transient.shape)
    assert (y, x) == (n - 1, 0)  # top (y up: the last row) on the left
